//! Encoding time and size of an EXR's channels under each lossless compression the `exr` crate
//! writes, on one thread and on all: `cargo run --release -p coordinator --example exr_speed --
//! OUT.exr` (the figures behind `output::ENCODING`). Fastest of five encodings each.
use std::time::Instant;

use anyhow::{Context, Result};
use exr::prelude::*;

fn main() -> Result<()> {
    let path = std::env::args().nth(1).context("usage: exr_speed FILE.exr")?;
    let image = read_all_flat_layers_from_file(&path).with_context(|| path.clone())?;
    let size = image.layer_data[0].size;
    // Every channel of every part, as one part.
    let channels: Vec<AnyChannel<FlatSamples>> =
        image.layer_data.iter().flat_map(|l| l.channel_data.list.iter().cloned()).collect();
    println!("{path}: {}x{}, {} channels", size.0, size.1, channels.len());
    let lines = |compression| Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    for (name, encoding) in [
        ("ZIP16", lines(Compression::ZIP16)),
        ("ZIP1", lines(Compression::ZIP1)),
        ("PIZ", lines(Compression::PIZ)),
        ("RLE", lines(Compression::RLE)),
        ("none", lines(Compression::Uncompressed)),
    ] {
        for parallel in [false, true] {
            let (mut best, mut bytes) = (f64::INFINITY, 0);
            for _ in 0..5 {
                let channels = AnyChannels::sort(SmallVec::from_vec(channels.clone()));
                let layer =
                    Layer::new(size, LayerAttributes::default(), encoding.clone(), channels);
                let mut out = std::io::Cursor::new(Vec::new());
                let start = Instant::now();
                let image = Image::from_layer(layer);
                if parallel {
                    image.write().to_buffered(&mut out)?;
                } else {
                    image.write().non_parallel().to_buffered(&mut out)?;
                }
                best = best.min(start.elapsed().as_secs_f64());
                bytes = out.into_inner().len();
            }
            let threads = if parallel { "all threads" } else { "one thread" };
            println!("{name:6} {threads:12} {:8.2} ms {bytes:10} bytes", best * 1e3);
        }
    }
    Ok(())
}
