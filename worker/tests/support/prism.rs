//! The prism's rainbow (`worker::test_scenes::PrismRainbow`): its scene as a file, its closed
//! form, and the column statistics the tests compare them by.

use common::film::Film;
use worker::test_scenes::PrismRainbow;

/// Writes the scene to a temporary folder tagged `tag` and returns the glTF's path.
pub fn scene(tag: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("renderfarm-prism-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("prism.gltf");
    std::fs::write(&path, PrismRainbow.gltf()).unwrap();
    path
}

/// The closed form's row of `width` pixels (every row is the same), from `entries` entry
/// points per lit face and wavelength.
pub fn expected(width: u32, entries: u32) -> Vec<[f64; 3]> {
    PrismRainbow::profile(width, entries)
}

/// Compares `ours` (`columns`) with `expected` column by column and channel by channel: the
/// largest, over them, of |difference| / (Sidak bound (1% over all of them) x the standard
/// error + `floor` x the brightest expected value), with where it is. Below 1 where they agree
/// within the noise; `floor` allows for the rare light that lands at the rainbow's faint ends,
/// which a few samples' variance does not see.
pub fn worst_column(
    ours: &[([f64; 3], [f64; 3])],
    expected: &[[f64; 3]],
    floor: f64,
) -> (f64, String) {
    let z_bound = super::sidak_z(0.01, 3 * ours.len());
    let peak = expected.iter().flatten().fold(0.0f64, |a, &b| a.max(b));
    let mut worst = (0.0f64, String::new());
    for (x, ((m, v), e)) in ours.iter().zip(expected).enumerate() {
        for c in 0..3 {
            let se = v[c].sqrt();
            let score = (m[c] - e[c]).abs() / (z_bound * se + floor * peak);
            if score > worst.0 {
                let z = (m[c] - e[c]) / se;
                worst = (
                    score,
                    format!("column {x}, channel {c}: {:.5} against {:.5}, z {z:.2}", m[c], e[c]),
                );
            }
        }
    }
    worst
}

/// Asserts that an image of the rainbow (its `columns`, `width` of them) agrees with the closed
/// form column by column (`worst_column` with `floor`), printing both profiles.
pub fn assert_matches_closed_form(ours: &[([f64; 3], [f64; 3])], width: u32, floor: f64) {
    let expected = expected(width, 2000);
    for (x, ((m, _), e)) in ours.iter().zip(&expected).enumerate() {
        println!(
            "column {x:2}: {:.4} {:.4} {:.4}   closed form {:.4} {:.4} {:.4}",
            m[0], m[1], m[2], e[0], e[1], e[2]
        );
    }
    let (score, at) = worst_column(&ours, &expected, floor);
    println!("prism rainbow: worst {score:.2} ({at})");
    assert!(score < 1.0, "{at}");
}

/// Per column and channel, the mean over equal `batches` (`render_sppm_batches`, `width` wide) of
/// their column means (each over the rows) and its variance from their spread: a pass's pixels
/// are not independent (they share its wavelength and photons), which `columns` assumes.
pub fn batch_columns(batches: &[Film], width: u32) -> Vec<([f64; 3], [f64; 3])> {
    let b = batches.len() as f64;
    let per_batch: Vec<Vec<([f64; 3], [f64; 3])>> =
        batches.iter().map(|f| columns(&super::pixel_stats(f), width)).collect();
    (0..width as usize)
        .map(|x| {
            let mut m = [0.0; 3];
            let mut v = [0.0; 3];
            for c in 0..3 {
                m[c] = per_batch.iter().map(|cols| cols[x].0[c]).sum::<f64>() / b;
                let ss: f64 = per_batch.iter().map(|cols| (cols[x].0[c] - m[c]).powi(2)).sum();
                v[c] = ss / (b - 1.0) / b;
            }
            (m, v)
        })
        .collect()
}

/// Per column and channel, the mean over the image's rows of the pixels' means (`stats` as
/// `pixel_stats` gives them, `width` wide) and its variance.
pub fn columns(stats: &[([f64; 3], [f64; 3])], width: u32) -> Vec<([f64; 3], [f64; 3])> {
    let rows = stats.len() / width as usize;
    (0..width as usize)
        .map(|x| {
            let mut m = [0.0; 3];
            let mut v = [0.0; 3];
            for y in 0..rows {
                let (pm, pv) = &stats[y * width as usize + x];
                for c in 0..3 {
                    m[c] += pm[c] / rows as f64;
                    v[c] += pv[c] / (rows * rows) as f64;
                }
            }
            (m, v)
        })
        .collect()
}
