//! The log writer of the one-shot commands (`render`, `submit`): each distinct warning reaches
//! stderr once. A command loads its scene more than once (to bundle it, and again as the farm
//! checks the upload), and the loader's warnings would otherwise repeat.

use std::{
    collections::HashSet,
    io::Write,
    sync::{Arc, Mutex},
};

use tracing::{Level, Metadata};
use tracing_subscriber::fmt::MakeWriter;

/// Writes log lines to stderr, a warning or error that was written already dropped.
#[derive(Clone, Debug, Default)]
pub struct OnceWarnings {
    seen: Arc<Mutex<HashSet<Vec<u8>>>>,
}

/// One event's line, written when the formatter is done with it.
pub struct Line {
    seen: Option<Arc<Mutex<HashSet<Vec<u8>>>>>,
    buf: Vec<u8>,
}

impl Write for Line {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.buf.extend_from_slice(bytes);
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for Line {
    fn drop(&mut self) {
        if self.buf.is_empty() {
            return;
        }
        if let Some(seen) = &self.seen {
            let mut seen = seen.lock().unwrap_or_else(|p| p.into_inner());
            if seen.contains(&self.buf) {
                return;
            }
            seen.insert(self.buf.clone());
        }
        let _ = std::io::stderr().write_all(&self.buf);
    }
}

impl<'a> MakeWriter<'a> for OnceWarnings {
    type Writer = Line;

    fn make_writer(&'a self) -> Line {
        Line { seen: None, buf: Vec::new() }
    }

    fn make_writer_for(&'a self, meta: &Metadata<'_>) -> Line {
        // Only warnings and errors are remembered: they are few, and the chatter that
        // `RUST_LOG=debug` asks for passes as it comes.
        let dedup = *meta.level() <= Level::WARN;
        Line { seen: dedup.then(|| self.seen.clone()), buf: Vec::new() }
    }
}
