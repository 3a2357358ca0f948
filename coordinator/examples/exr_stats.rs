//! Prints the per-channel mean of an EXR and, given a reference, RMSE and relative MSE
//! (the peers harness's metrics): `cargo run --release --example exr_stats -- OUT.exr [REF.exr]`.

use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let args: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    let (w, h, img) = coordinator::output::read_exr_rgb(&args[0])?;
    let n = (w * h) as f64;
    let mean = [0, 1, 2].map(|c| img.iter().map(|p| p[c] as f64).sum::<f64>() / n);
    println!("{w}x{h} mean {mean:?}");
    if let Some(reference) = args.get(1) {
        let (_, _, r) = coordinator::output::read_exr_rgb(reference)?;
        let (mut se, mut rel) = (0.0, 0.0);
        for (a, b) in img.iter().zip(&r) {
            for c in 0..3 {
                let d = a[c] as f64 - b[c] as f64;
                se += d * d;
                rel += d * d / (b[c] as f64 * b[c] as f64 + 0.01);
            }
        }
        println!("rmse {:.6} relmse {:.6e}", (se / (3.0 * n)).sqrt(), rel / (3.0 * n));
    }
    Ok(())
}
