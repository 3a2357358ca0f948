//! Exits 0 when two EXR files hold the same channels with bit-identical pixels (headers, such as
//! the render time, may differ), else prints the first difference and exits 1. Optionally checks
//! that the `samples` channel is N everywhere: `exr_same A.exr B.exr [--samples N]`.

use anyhow::{bail, Context, Result};

fn channels(path: &str) -> Result<Vec<(String, Vec<u32>)>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {path}"))?;
    coordinator::output::read_channel_bits(&bytes).with_context(|| path.to_string())
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (a, b) = match args.as_slice() {
        [a, b, ..] => (a, b),
        _ => bail!("usage: exr_same A.exr B.exr [--samples N]"),
    };
    let samples: Option<u32> = match args.get(2).map(String::as_str) {
        Some("--samples") => Some(args.get(3).context("--samples N")?.parse()?),
        _ => None,
    };
    let (ca, cb) = (channels(a)?, channels(b)?);
    let names = |c: &[(String, Vec<u32>)]| c.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    if names(&ca) != names(&cb) {
        bail!("channels differ: {:?} vs {:?}", names(&ca), names(&cb));
    }
    for ((name, va), (_, vb)) in ca.iter().zip(&cb) {
        if let Some(i) = va.iter().zip(vb).position(|(x, y)| x != y) {
            let diff = va.iter().zip(vb).filter(|(x, y)| x != y).count();
            bail!("channel {name} differs in {diff} of {} pixels (first: pixel {i})", va.len());
        }
        if name == "samples" {
            if let Some(n) = samples {
                if let Some(i) = va.iter().position(|&s| s != n) {
                    bail!("pixel {i} has {} samples, not {n}", va[i]);
                }
            }
        }
    }
    println!("{a} and {b}: identical ({} channels)", ca.len());
    Ok(())
}
