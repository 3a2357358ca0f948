//! Helpers shared by the scene tests: locating the test scenes, rendering a whole frame in-process,
//! reading reference EXRs, and the variance-derived statistics the assertions use.

#![allow(dead_code, unreachable_pub)]

pub mod prism;

use std::path::{Path, PathBuf};

use common::{
    film::{Film, Rect},
    protocol::{SampleRange, TaskKind, TaskSpec},
    scene::Scene,
    settings::RenderSettings,
};
use worker::render::{
    render_task, render_task_threads,
    scene::{prepare, prepare_frame, PreparedScene},
};

/// The repository's `scenes/`: the scenes made for the renderer, with their references in `ref/`.
pub fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

/// The repository's `tests/assets/`: the third-party files the tests read (Khronos sample assets
/// in `real/`, each with its licence, and the environment map in `real/environments/`).
pub fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets")
}

/// Loads a scene under `scenes/`.
pub fn load(name: &str) -> Scene {
    let path = scenes().join(name);
    common::gltf::load_path(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Reads `scenes/<name>.settings.json`.
pub fn settings(name: &str) -> RenderSettings {
    let path = scenes().join(format!("{name}.settings.json"));
    RenderSettings::from_json(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

/// Renders every pixel of frame 0 for samples [0, spp), tiles spread over two threads.
pub fn render(scene: &Scene, settings: &RenderSettings) -> Film {
    render_prepared(&prepare(scene, settings).expect("prepare"), settings)
}

/// `render` for frame 0 of an animated scene (posed at its time, what moves within the
/// shutter blurred); the same as `render` for a still one.
pub fn render_frame0(scene: &Scene, settings: &RenderSettings) -> Film {
    render_prepared(&prepare_frame(scene, settings, None, 0).expect("prepare"), settings)
}

/// `render` for an already prepared scene.
pub fn render_prepared(prepared: &PreparedScene, settings: &RenderSettings) -> Film {
    let mut tasks = Vec::new();
    let tile = 32;
    for y0 in (0..settings.height).step_by(tile) {
        for x0 in (0..settings.width).step_by(tile) {
            let rect = Rect {
                x0,
                y0,
                width: (tile as u32).min(settings.width - x0),
                height: (tile as u32).min(settings.height - y0),
            };
            tasks.push(TaskSpec {
                frame: 0,
                rect,
                samples: SampleRange { start: 0, end: settings.spp },
                kind: TaskKind::Camera,
            });
        }
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let film = std::sync::Mutex::new(Film::new(settings.width, settings.height));
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(task) = tasks.get(i) else { break };
                let result = render_task(prepared, settings.seed, task);
                film.lock().unwrap().merge_tile(&result.tile);
            });
        }
    });
    film.into_inner().unwrap()
}

/// Reads the R, G, B channels of an EXR, row-major.
pub fn read_rgb(path: &Path) -> (usize, usize, Vec<[f32; 3]>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let (w, h, texels) = common::envmap::read_exr_rgb(&bytes, u64::MAX)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (w, h, texels.iter().map(|t| t.to_array()).collect())
}

/// Result of comparing a rendered film against an expected image.
#[derive(Debug)]
pub struct Comparison {
    /// Pooled z-score of the whole image: sum of differences / sqrt(sum of variances).
    pub z_image: f64,
    /// Largest |z| over square blocks of pixels.
    pub z_block_max: f64,
    /// Number of blocks.
    pub blocks: usize,
    /// Measured RMSE against the expectation.
    pub rmse: f64,
    /// RMSE predicted by the film's own variance estimate.
    pub predicted_rmse: f64,
}

/// Compares `film` with `expected` (row-major RGB) whose own noise variance per value is
/// `expected_var`. Pixels where the film reports zero variance and matches exactly count as
/// exact; blocks are `block` x `block` pixels.
pub fn compare(film: &Film, expected: &[[f32; 3]], expected_var: f64, block: u32) -> Comparison {
    let (w, h) = (film.width, film.height);
    let bx = w.div_ceil(block);
    let by = h.div_ceil(block);
    let mut block_sums = vec![(0.0f64, 0.0f64); (bx * by) as usize];
    let (mut d_sum, mut v_sum, mut sq_err) = (0.0, 0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let mean = film.pixels[i].mean();
            let var = film.pixels[i].variance_of_mean();
            for c in 0..3 {
                let d = mean[c] - expected[i][c] as f64;
                let v = var[c] + expected_var;
                assert!(v.is_finite(), "pixel ({x}, {y}) has no variance estimate");
                d_sum += d;
                v_sum += v;
                sq_err += d * d;
                let b = &mut block_sums[((y / block) * bx + x / block) as usize];
                b.0 += d;
                b.1 += v;
            }
        }
    }
    let n = (w * h * 3) as f64;
    let z = |(d, v): (f64, f64)| {
        if v > 0.0 {
            d / v.sqrt()
        } else if d == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    };
    Comparison {
        z_image: z((d_sum, v_sum)),
        z_block_max: block_sums.iter().map(|&b| z(b).abs()).fold(0.0, f64::max),
        blocks: block_sums.len(),
        rmse: (sq_err / n - expected_var).max(0.0).sqrt(),
        predicted_rmse: film.error_estimate().rmse,
    }
}

/// Two-sided normal quantile for the Sidak-corrected level `alpha` over `tests` tests.
pub fn sidak_z(alpha: f64, tests: usize) -> f64 {
    let a = 1.0 - (1.0 - alpha).powf(1.0 / tests as f64);
    // Inverse of erfc via bisection: P(|Z| > z) = a.
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if erfc(mid / std::f64::consts::SQRT_2) > a {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Complementary error function (Numerical Recipes erfcc, relative error < 1.2e-7).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    // Horner's rule from the highest power down (one level of nesting: rustfmt takes seconds
    // over the same polynomial written as nested parentheses).
    const C: [f64; 8] = [
        0.374_091_96,
        0.096_784_18,
        -0.186_288_06,
        0.278_868_07,
        -1.135_203_98,
        1.488_515_87,
        -0.822_152_23,
        0.170_872_77,
    ];
    let mut poly = C[7];
    for &c in C[..7].iter().rev() {
        poly = c + t * poly;
    }
    let r = t * (-z * z - 1.265_512_23 + t * (1.000_023_68 + t * poly)).exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

/// A copy of `scenes/<name>.gltf` in a fresh temporary folder (with its `.bin`), after
/// `edit` has changed its JSON. Returns the new path.
pub fn edited_scene(name: &str, tag: &str, edit: impl FnOnce(&mut serde_json::Value)) -> PathBuf {
    let src = scenes().join(format!("{name}.gltf"));
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&src).unwrap()).unwrap();
    edit(&mut json);
    let dir = std::env::temp_dir().join(format!("renderfarm-test-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(scenes().join(format!("{name}.bin")), dir.join(format!("{name}.bin"))).unwrap();
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// Wraps every root node of the default scene under one new node with the given TRS.
pub fn wrap_roots(json: &mut serde_json::Value, node: serde_json::Value) {
    let scene_idx = json["scene"].as_u64().unwrap_or(0) as usize;
    let roots = json["scenes"][scene_idx]["nodes"].clone();
    let nodes = json["nodes"].as_array_mut().unwrap();
    let mut node = node;
    node["children"] = roots;
    nodes.push(node);
    let new_idx = nodes.len() - 1;
    json["scenes"][scene_idx]["nodes"] = serde_json::json!([new_idx]);
}

/// Standard base64 (for data URIs in generated scenes).
pub fn base64(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The largest distance of any pixel's channel from 1 (a white furnace's answer).
pub fn worst_from_white(film: &Film) -> f64 {
    film.mean_rgb().iter().flatten().map(|&v| (v as f64 - 1.0).abs()).fold(0.0, f64::max)
}

/// Render settings for a white furnace: `res` x `res` pixels, `spp` samples, a uniform white
/// environment, 256 bounces.
pub fn white_furnace(res: u32, spp: u32) -> RenderSettings {
    RenderSettings {
        width: res,
        height: res,
        spp,
        max_depth: 256,
        environment: Some(common::settings::Environment::Color { color: [1.0; 3] }),
        ..Default::default()
    }
}

/// A smooth, fully transmitting, non-metallic glTF material of index `ior` bounding a volume
/// (`thicknessFactor`) that absorbs to `attenuation` (colour, distance) when given.
pub fn dielectric_material(
    ior: f64,
    thickness: f64,
    attenuation: Option<([f64; 3], f64)>,
) -> serde_json::Value {
    let mut volume = serde_json::json!({"thicknessFactor": thickness});
    if let Some((color, distance)) = attenuation {
        volume["attenuationColor"] = serde_json::json!(color);
        volume["attenuationDistance"] = serde_json::json!(distance);
    }
    serde_json::json!({
        "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.0},
        "extensions": {
            "KHR_materials_transmission": {"transmissionFactor": 1.0},
            "KHR_materials_volume": volume,
            "KHR_materials_ior": {"ior": ior}
        }
    })
}

/// The mean of each channel over the image and its standard error.
pub fn image_mean(film: &Film) -> [(f64, f64); 3] {
    let n = film.pixels.len() as f64;
    let means = film.mean_rgb();
    std::array::from_fn(|c| {
        let mean = means.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let var: f64 = film.pixels.iter().map(|p| p.variance_of_mean()[c]).sum::<f64>() / n;
        (mean, (var / n).sqrt())
    })
}

/// Loads a `MirrorCaustic` scene (written to a temporary file).
pub fn load_caustic(caustic: &worker::test_scenes::MirrorCaustic) -> Scene {
    let dir = std::env::temp_dir().join(format!("renderfarm-caustic-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("caustic-{}.gltf", caustic.light_half_side));
    std::fs::write(&path, caustic.gltf()).unwrap();
    common::gltf::load_path(&path).unwrap()
}

/// Every pixel's expected value in a `MirrorCaustic` image (the closed form averaged over its
/// footprint), grey.
pub fn caustic_expected(caustic: &worker::test_scenes::MirrorCaustic, res: u32) -> Vec<[f32; 3]> {
    (0..res * res).map(|i| [caustic.pixel_radiance(i % res, i / res, res, res) as f32; 3]).collect()
}

/// The benchmark's mirror caustic (`bench --caustic`: light half side 0.125, radiance
/// 7.5 / 0.125²) at `res` x `res`: the scene, each pixel's closed form, and settings for it
/// (`max_depth` 2, seed 7, `spp` samples).
pub fn bench_caustic(res: u32, spp: u32) -> (Scene, Vec<[f32; 3]>, RenderSettings) {
    caustic_with_light(0.125, res, spp)
}

/// [`bench_caustic`] with a light of half side `half` (`bench --caustic-light`: its radiance
/// 7.5 / half², the caustic as bright).
pub fn caustic_with_light(half: f64, res: u32, spp: u32) -> (Scene, Vec<[f32; 3]>, RenderSettings) {
    let caustic =
        worker::test_scenes::MirrorCaustic { light_half_side: half, radiance: 7.5 / (half * half) };
    let settings = RenderSettings {
        width: res,
        height: res,
        spp,
        max_depth: 2,
        seed: 7,
        ..Default::default()
    };
    (load_caustic(&caustic), caustic_expected(&caustic, res), settings)
}

/// The Cornell box's depth-of-field settings (`scenes/cornell-dof.settings.json`: its thin lens).
pub fn cornell_dof_settings() -> RenderSettings {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-dof.settings.json");
    RenderSettings::from_json(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The Cornell box whose blocks move within the shutter (`scenes/cornell-motion`: the short
/// block slides 6 cm, the tall one turns) with its settings; with `moving_camera`, the camera
/// rides a node that slides as the short block does (written to a temporary file).
pub fn cornell_motion(moving_camera: bool) -> (Scene, RenderSettings) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let settings = RenderSettings::from_json(
        &std::fs::read_to_string(dir.join("cornell-motion.settings.json")).unwrap(),
    )
    .unwrap();
    let src = dir.join("cornell-motion.gltf");
    if !moving_camera {
        return (common::gltf::load_path(&src).unwrap(), settings);
    }
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&src).unwrap()).unwrap();
    let camera = json["nodes"].as_array().unwrap().iter().position(|n| n.get("camera").is_some());
    let camera = camera.expect("a camera node");
    let nodes = json["nodes"].as_array_mut().unwrap();
    nodes.push(serde_json::json!({"name": "camera-rig", "children": [camera]}));
    let rig = nodes.len() - 1;
    let roots = json["scenes"][0]["nodes"].as_array_mut().unwrap();
    roots.retain(|n| n.as_u64() != Some(camera as u64));
    roots.push(serde_json::json!(rig));
    // The short block's translation sampler (0 to 6 cm along x over the shutter) moves the rig.
    json["animations"][0]["channels"]
        .as_array_mut()
        .unwrap()
        .push(serde_json::json!({"sampler": 0, "target": {"node": rig, "path": "translation"}}));
    let out = std::env::temp_dir().join(format!("renderfarm-motion-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::copy(dir.join("cornell-box.bin"), out.join("cornell-box.bin")).unwrap();
    let path = out.join("cornell-motion-camera.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    (common::gltf::load_path(&path).unwrap(), settings)
}

/// Per pixel of a film: the mean and the variance of the mean of each channel.
pub fn pixel_stats(film: &Film) -> Vec<([f64; 3], [f64; 3])> {
    film.pixels.iter().map(|p| (p.mean(), p.variance_of_mean())).collect()
}

/// Compares two images block by block (`block` x `block` pixels, channels summed): the largest,
/// over the blocks, of |difference| / (Sidak bound (1% over all blocks) x the standard error of
/// the difference + `bias` x the reference's sum). Below 1 where the images agree within the
/// noise; `what` names the worst block in the returned text.
pub fn worst_block(
    ours: &[([f64; 3], [f64; 3])],
    reference: &[([f64; 3], [f64; 3])],
    width: u32,
    block: u32,
    bias: f64,
) -> (f64, String) {
    worst_block_by(ours, reference, width, block, bias, &[&[0, 1, 2]])
}

/// `worst_block` for each colour channel alone (a wrong colour with the right brightness shows
/// here): the worst over the blocks and channels, with the Sidak bound over all of them.
pub fn worst_channel_block(
    ours: &[([f64; 3], [f64; 3])],
    reference: &[([f64; 3], [f64; 3])],
    width: u32,
    block: u32,
    bias: f64,
) -> (f64, String) {
    worst_block_by(ours, reference, width, block, bias, &[&[0], &[1], &[2]])
}

/// `worst_block` over each group of channels (summed within the group), the Sidak bound over
/// the blocks of every group.
fn worst_block_by(
    ours: &[([f64; 3], [f64; 3])],
    reference: &[([f64; 3], [f64; 3])],
    width: u32,
    block: u32,
    bias: f64,
    groups: &[&[usize]],
) -> (f64, String) {
    let height = ours.len() as u32 / width;
    let blocks = ((width / block) * (height / block)) as usize;
    let z_bound = sidak_z(0.01, groups.len() * blocks);
    let mut worst = (0.0f64, String::new());
    for &group in groups {
        for by in 0..height / block {
            for bx in 0..width / block {
                let (mut a, mut b, mut var) = (0.0, 0.0, 0.0);
                for y in by * block..(by + 1) * block {
                    for x in bx * block..(bx + 1) * block {
                        let i = (y * width + x) as usize;
                        for &c in group {
                            a += ours[i].0[c];
                            b += reference[i].0[c];
                            var += ours[i].1[c] + reference[i].1[c];
                        }
                    }
                }
                let score = (a - b).abs() / (z_bound * var.sqrt() + bias * b.abs());
                if score > worst.0 {
                    let z = (a - b) / var.sqrt();
                    let which = match group {
                        [c] => format!("channel {c}, "),
                        _ => String::new(),
                    };
                    worst =
                        (score, format!("{which}block ({bx}, {by}): ratio {:.4}, z {z:.2}", a / b));
                }
            }
        }
    }
    worst
}

/// The dispersive slab edge: a slab of thickness 0.5, index 1.5 and dispersion 2 tilted 30
/// degrees over an emitting half-plane (`box_scene`), seen from above by an orthographic camera
/// at `width` x `width`, and settings of 64 samples per pixel.
pub fn dispersive_slab_edge(tag: &str, width: u32) -> (PathBuf, RenderSettings) {
    let mut material = dielectric_material(1.5, 1.0, None);
    material["extensions"]["KHR_materials_dispersion"] = serde_json::json!({"dispersion": 2.0});
    let half = [20.0, 0.25, 20.0];
    let path = box_scene(tag, half, [0.0; 3], material, 3.0, 1.0, 30f64.to_radians(), true);
    let settings =
        RenderSettings { width, height: width, spp: 64, max_depth: 16, ..Default::default() };
    (path, settings)
}

/// Asserts that the image of `dispersive_slab_edge` (`stats` per pixel, `width` wide, pixels
/// independent) shows the edge where each channel's colour-weighted Snell offset puts it, within
/// four standard errors (plus a fiftieth of a pixel), and blue moved more than red.
pub fn assert_edge_split_by_colour(stats: &[([f64; 3], [f64; 3])], width: u32) {
    let pixel = 2.0 / width as f64;
    let w = width as usize;
    check_slab_edges(width, |c, guess| {
        let columns: Vec<(f64, f64)> = (0..w)
            .map(|i| {
                let mean = (0..w).map(|row| stats[row * w + i].0[c]).sum::<f64>();
                let var = (0..w).map(|row| stats[row * w + i].1[c]).sum::<f64>();
                (mean / w as f64, var / (w * w) as f64)
            })
            .collect();
        let means: Vec<f64> = columns.iter().map(|c| c.0).collect();
        let (centre, far) = edge_windows(w, pixel, guess);
        let level = means[far.clone()].iter().sum::<f64>() / 16.0;
        let level_var = columns[far].iter().map(|c| c.1).sum::<f64>() / 256.0;
        let lit = means[centre.clone()].iter().sum::<f64>() * pixel;
        let lit_var = columns[centre].iter().map(|c| c.1).sum::<f64>() * pixel * pixel;
        let se = (lit_var / (level * level) + (lit / level).powi(2) * level_var / (level * level))
            .sqrt();
        (slab_edge(&means, pixel, guess), se)
    });
}

/// `assert_edge_split_by_colour` for an image rendered as independent `batches` of samples whose
/// pixels are not independent within a batch (photon mapping: a pass's pixels share its
/// wavelength and its photons): the standard error from the spread of the batches' edges.
pub fn assert_edge_split_by_colour_in_batches(batches: &[Film], width: u32) {
    let pixel = 2.0 / width as f64;
    let w = width as usize;
    let column_means = |films: &[&Film], c: usize| -> Vec<f64> {
        let n = (films.len() * w) as f64;
        (0..w)
            .map(|i| {
                films
                    .iter()
                    .map(|f| (0..w).map(|row| f.pixels[row * w + i].mean()[c]).sum::<f64>())
                    .sum::<f64>()
                    / n
            })
            .collect()
    };
    let all: Vec<&Film> = batches.iter().collect();
    check_slab_edges(width, |c, guess| {
        let edge = slab_edge(&column_means(&all, c), pixel, guess);
        let edges: Vec<f64> =
            batches.iter().map(|b| slab_edge(&column_means(&[b], c), pixel, guess)).collect();
        let b = edges.len() as f64;
        let mean = edges.iter().sum::<f64>() / b;
        let var = edges.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / (b - 1.0);
        (edge, (var / b).sqrt())
    });
}

/// The columns that `slab_edge` reads for `guess`: the window of 20 around it and the 16 far
/// right.
fn edge_windows(
    w: usize,
    pixel: f64,
    guess: f64,
) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
    let centre = ((guess + 1.0) / pixel) as usize;
    (centre - 10..centre + 10, w - 16..w)
}

/// The edge, linearly in the image (a mixture of wavelengths is a mixture of edges), from a
/// channel's column means: over a window of 20 columns around `guess`, the lit area of the mean
/// row over the level far right, taken from the window's right end. The window leaves out the
/// faint ghost edge of light reflected twice inside the slab, which lies farther along.
fn slab_edge(columns: &[f64], pixel: f64, guess: f64) -> f64 {
    let (window, far) = edge_windows(columns.len(), pixel, guess);
    let right = -1.0 + window.end as f64 * pixel;
    let level = columns[far].iter().sum::<f64>() / 16.0;
    let lit = columns[window].iter().sum::<f64>() * pixel;
    right - lit / level
}

/// Checks each channel's edge (`edge(channel, guess)`: the measured edge and its standard error)
/// against the Snell offsets of `dispersive_slab_edge`'s slab weighted by the channel's colour of
/// each wavelength and the slab's transmittance (1 - F) / (1 + F) at it, within four standard
/// errors plus a fiftieth of a pixel; and blue moved more than red.
fn check_slab_edges(width: u32, edge: impl Fn(usize, f64) -> (f64, f64)) {
    let (ior, dispersion, thickness, tilt) = (1.5f64, 2.0f64, 0.5f64, 30f64.to_radians());
    // The orthographic view is 2 x 2.
    let pixel = 2.0 / width as f64;
    let expected = |c: usize| {
        let (mut num, mut den) = (0.0, 0.0);
        for k in 0..4700 {
            let lambda = 360.0 + (k as f32 + 0.5) / 10.0;
            let n = worker::render::spectrum::dispersive_ior(ior as f32, dispersion as f32, lambda)
                as f64;
            let theta_t = (tilt.sin() / n).asin();
            let shift = thickness * (tilt - theta_t).sin() / theta_t.cos();
            let f = worker::render::bsdf::fresnel_dielectric(tilt.cos() as f32, n as f32) as f64;
            let weight =
                worker::render::spectrum::rgb_weights(lambda)[c] as f64 * (1.0 - f) / (1.0 + f);
            num += weight * -shift;
            den += weight;
        }
        num / den
    };
    let mut at = [0.0; 3];
    for c in 0..3 {
        let e = expected(c);
        let (measured, se) = edge(c, e);
        at[c] = measured;
        eprintln!(
            "channel {c}: the edge at {measured:.5} +- {se:.5}, the law puts it at {e:.5} (a pixel is {pixel:.5})"
        );
        // The ghost left in the window is worth at most about a fiftieth of a pixel.
        assert!(
            (measured - e).abs() < 4.0 * se + 0.02 * pixel,
            "channel {c}: {measured} against {e}"
        );
    }
    assert!(at[2] < at[0], "blue moves more than red: {at:?}");
}

/// Photon mapping of frame 0 as `render_sppm_with`, each `batch` passes (`threads` threads)
/// rendered into a film of its own: batches of passes are independent, where the pixels of one
/// pass are not (they share its wavelength, hero channel and photons).
pub fn render_sppm_batches(
    scene: &Scene,
    settings: &RenderSettings,
    batch: u32,
    threads: usize,
) -> Vec<Film> {
    let settings =
        RenderSettings { integrator: common::settings::Integrator::Sppm, ..settings.clone() };
    let prepared = prepare_frame(scene, &settings, None, 0).expect("prepare");
    let rect = Rect { x0: 0, y0: 0, width: settings.width, height: settings.height };
    (0..settings.spp.div_ceil(batch))
        .map(|b| {
            let samples =
                SampleRange { start: b * batch, end: ((b + 1) * batch).min(settings.spp) };
            let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
            let mut film = Film::new(settings.width, settings.height);
            film.merge_tile(&render_task_threads(&prepared, settings.seed, &task, threads).tile);
            film
        })
        .collect()
}

/// Each channel's image mean over equal `batches` (`render_sppm_batches`) and its standard error
/// from the spread of the batches' image means (`image_mean` sums the pixels' variances, which
/// only holds where pixels are independent).
pub fn batch_mean_image(batches: &[Film]) -> [(f64, f64); 3] {
    let b = batches.len() as f64;
    let image: Vec<[f64; 3]> = batches
        .iter()
        .map(|f| {
            let n = f.pixels.len() as f64;
            std::array::from_fn(|c| f.pixels.iter().map(|p| p.mean()[c]).sum::<f64>() / n)
        })
        .collect();
    std::array::from_fn(|c| {
        let mean = image.iter().map(|m| m[c]).sum::<f64>() / b;
        let var = image.iter().map(|m| (m[c] - mean) * (m[c] - mean)).sum::<f64>() / (b - 1.0);
        (mean, (var / b).sqrt())
    })
}

/// `dielectric_material` filling a scattering medium: `attenuation` (colour, distance) is the
/// extinction, `multiscatter` and `g` the `KHR_materials_volume_scatter` values.
pub fn scattering(
    ior: f64,
    attenuation: ([f64; 3], f64),
    multiscatter: [f64; 3],
    g: f64,
) -> serde_json::Value {
    let mut m = dielectric_material(ior, 1.0, Some(attenuation));
    m["extensions"]["KHR_materials_volume_scatter"] =
        serde_json::json!({"multiscatterColor": multiscatter, "scatterAnisotropy": g});
    m
}

/// Scattering media of albedo 1 in the white furnace, where every pixel is 1 (each channel's
/// image mean within the noise): a box of a medium whose extinction differs per channel behind
/// an index-matched boundary, one behind a diffusely transmitting boundary, and one of glass
/// (ior 1.5) over a white Lambertian floor. Returns (name, the glTF's path) for each.
pub fn scattering_furnaces(tag: &str) -> Vec<(&'static str, PathBuf)> {
    let chromatic = scattering(1.0, ([0.1, 0.5, 0.9], 0.3), [1.0; 3], -0.3);
    let mut diffuse_boundary = scattering(1.0, ([0.2; 3], 0.3), [1.0; 3], 0.0);
    diffuse_boundary["extensions"]["KHR_materials_transmission"]["transmissionFactor"] =
        serde_json::json!(0.0);
    diffuse_boundary["extensions"]["KHR_materials_specular"] =
        serde_json::json!({"specularFactor": 0.0});
    diffuse_boundary["extensions"]["KHR_materials_diffuse_transmission"] =
        serde_json::json!({"diffuseTransmissionFactor": 1.0});
    let mut out = vec![
        ("chromatic", furnace_box(&format!("{tag}-chromatic"), chromatic)),
        ("diffuse boundary", furnace_box(&format!("{tag}-diffuse-boundary"), diffuse_boundary)),
    ];
    let glass = scattering(1.5, ([0.2, 0.35, 0.5], 0.1), [1.0; 3], 0.3);
    out.push(("glass over a floor", medium_over_floor(&format!("{tag}-floor"), glass)));
    out
}

/// A box of `material` over a white Lambertian floor (`box_scene`'s half-plane, x > 0 at
/// y = -1, made a floor), seen from above; returns the glTF's path.
pub fn medium_over_floor(tag: &str, material: serde_json::Value) -> PathBuf {
    let path = box_scene(tag, [0.6, 0.4, 0.5], [0.1, -0.55, -0.2], material, 3.0, 1.0, 0.0, true);
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    json["materials"][1] = serde_json::json!({
        "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0},
        "doubleSided": true,
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
    });
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// Asserts each channel's image mean (`means`, with standard errors) is 1 within four standard
/// errors plus `bias`, naming `what`.
pub fn assert_white(what: &str, means: [(f64, f64); 3], bias: f64) {
    for (c, (mean, se)) in means.into_iter().enumerate() {
        println!("{what}, channel {c}: {mean:.5} (standard error {se:.1e})");
        assert!((mean - 1.0).abs() < 4.0 * se + bias + 1e-5, "{what}, channel {c}: {mean} ({se})");
    }
}

/// `cornell_under_water` with its water made a fog: five times the extinction (optical depths
/// about 4, 2 and 0.6 across it in red, green and blue, so that the free flights' channels
/// differ), an albedo of 0.95, 0.85 and 0.7 and forward scattering (g 0.4). Paths inside meet
/// the floor, the block and the red wall through it.
pub fn cornell_in_fog() -> Scene {
    let mut scene = cornell_under_water();
    make_fog(&mut scene, |extinction| extinction * 5.0, [0.95, 0.85, 0.7], 0.4);
    scene
}

/// Turns the scene's one volume (asserted) into a fog: its extinction mapped by `extinction`,
/// albedo `albedo` and Henyey-Greenstein `g`.
fn make_fog(
    scene: &mut Scene,
    extinction: impl Fn(glam::Vec3) -> glam::Vec3,
    albedo: [f32; 3],
    g: f32,
) {
    let mut fog = 0;
    for m in scene.materials.iter_mut().filter(|m| m.volume.is_some() && m.bounds_medium()) {
        let v = m.volume.as_mut().unwrap();
        v.extinction = extinction(v.extinction);
        v.albedo = glam::Vec3::from(albedo);
        v.anisotropy = g;
        assert!(v.scatters());
        fog += 1;
    }
    assert_eq!(fog, 1, "one volume");
}

/// The Cornell box and its camera inside a fog bank: a box of fog around the whole scene (index
/// 1; extinction 0.7, 0.45 and 0.25 a unit in red, green and blue, about 0.9, 0.6 and 0.3 in
/// optical depth from the camera to the back wall; albedo 0.9, 0.8 and 0.7; forward scattering,
/// g 0.3), so that camera paths start in it, the light lies in it and light tracing reaches the
/// camera through it.
pub fn cornell_in_a_fog_bank() -> Scene {
    let path = edited_scene("cornell-box", "fog-bank", |j| {
        let material = push_water(j);
        push_box(j, [-0.3, -0.3, -1.2], [0.9, 0.9, 0.9], material as usize);
    });
    let mut scene = common::gltf::load_path(&path).unwrap();
    make_fog(&mut scene, |_| glam::Vec3::new(0.7, 0.45, 0.25), [0.9, 0.8, 0.7], 0.3);
    scene
}

/// The Cornell box with its glass sphere (`scenes/cornell-glass`) made dispersive: `dispersion`
/// 2 (an Abbe number of 10, about three times a dense flint's spread), so that the caustic the
/// sphere throws on the floor splits into colours.
pub fn cornell_dispersive_glass() -> Scene {
    let mut scene = repo_scene("cornell-glass.gltf");
    let mut glass = 0;
    for m in scene.materials.iter_mut().filter(|m| m.refracts()) {
        m.dispersion = 2.0;
        glass += 1;
    }
    assert_eq!(glass, 1, "cornell-glass has one refractive material");
    scene
}

/// `cornell_motion`'s scene with its light moved by the short block's node (it slides 6 cm with
/// it: the scene's nodes carry no transform of their own).
pub fn with_moving_light(scene: &Scene) -> Scene {
    let mut moved = scene.clone();
    let anim = moved.animation.as_ref().expect("an animated scene");
    let emits = |i: &common::scene::Instance| {
        moved.materials[moved.meshes[i.mesh].material].emissive.max_element() > 0.0
    };
    let light = moved.instances.iter().position(emits).expect("an emissive mesh");
    let block = moved.instances.iter().position(|i| anim.moves(i.node)).expect("a moving mesh");
    moved.instances[light].node = moved.instances[block].node;
    moved
}

/// The Cornell box lit from outside as well: a sun (a directional light of irradiance 3 shining
/// in through the open front, down and to the side) and the studio environment map
/// (`tests/assets/real/environments`, seen through the front) besides its ceiling light. Returns
/// the scene, settings with the map (`max_depth` 5, 32 x 32) and the decoded map.
pub fn cornell_sun_and_sky() -> (Scene, RenderSettings, common::envmap::EnvMap) {
    let path = edited_scene("cornell-box", "sun", |j| {
        let used = j["extensionsUsed"].as_array_mut().unwrap();
        used.push(serde_json::json!("KHR_lights_punctual"));
        j["extensions"] = serde_json::json!({"KHR_lights_punctual": {"lights": [
            {"type": "directional", "intensity": 3.0, "color": [1.0, 0.9, 0.8]}
        ]}});
        // Rotates -z (where the light shines) onto (0.3, -0.5, 1) normalised.
        j["nodes"].as_array_mut().unwrap().push(serde_json::json!({
            "name": "sun",
            "rotation": [-0.827795714351693, -0.49667742861101577, 0.0, 0.26089420692939874],
            "extensions": {"KHR_lights_punctual": {"light": 0}}
        }));
        let sun = j["nodes"].as_array().unwrap().len() - 1;
        j["scenes"][0]["nodes"].as_array_mut().unwrap().push(serde_json::json!(sun));
    });
    let scene = common::gltf::load_path(&path).unwrap();
    let map_path = assets().join("real/environments/studio_small_05_1k.hdr");
    let map = common::envmap::EnvMap::load(&map_path).unwrap();
    let settings = RenderSettings {
        width: 32,
        height: 32,
        max_depth: 5,
        environment: Some(common::settings::Environment::Map {
            map: map_path.display().to_string(),
            intensity: 1.0,
            rotation_deg: 0.0,
            visible: true,
        }),
        ..settings("cornell-box")
    };
    (scene, settings, map)
}

/// The exact image of `scenes/furnace` (`ref/furnace.exr`, 256 x 256) box-filtered down
/// to `res` x `res` pixels (256 a multiple of `res`): covered pixels 0.8, the background 1.
pub fn furnace_expected(res: u32) -> Vec<[f32; 3]> {
    let (w, _, reference) = read_rgb(&scenes().join("ref/furnace.exr"));
    let k = w as u32 / res;
    (0..res * res)
        .map(|i| {
            let (x, y) = (i % res, i / res);
            let mut sum = [0.0f64; 3];
            for yy in y * k..(y + 1) * k {
                for xx in x * k..(x + 1) * k {
                    let p = reference[(yy * w as u32 + xx) as usize];
                    for c in 0..3 {
                        sum[c] += p[c] as f64;
                    }
                }
            }
            sum.map(|v| (v / (k * k) as f64) as f32)
        })
        .collect()
}

/// A box of half sizes `half` centred at `center` and turned by `tilt` radians about the z axis,
/// faces wound counter-clockwise seen from outside, with `material`; an orthographic camera at
/// height `camera_y` looking down on a square of half size `view`; and, when `edge`, an emitting
/// half-plane (radiance 1, facing up) at y = -1 under it, lit for x > 0 only. Returns the file's
/// path.
#[allow(clippy::too_many_arguments)]
pub fn box_scene(
    tag: &str,
    half: [f32; 3],
    center: [f32; 3],
    material: serde_json::Value,
    camera_y: f32,
    view: f32,
    tilt: f64,
    edge: bool,
) -> std::path::PathBuf {
    let [hx, hy, hz] = half;
    let [cx, cy, cz] = center;
    let corner = |i: usize| {
        [
            cx + if i & 1 == 1 { hx } else { -hx },
            cy + if i & 2 == 2 { hy } else { -hy },
            cz + if i & 4 == 4 { hz } else { -hz },
        ]
    };
    let positions: Vec<[f32; 3]> = (0..8).map(corner).collect();
    // Each face as a quad counter-clockwise seen from outside.
    let faces: [[u16; 4]; 6] = [
        [0, 4, 6, 2], // -x
        [1, 3, 7, 5], // +x
        [0, 1, 5, 4], // -y
        [2, 6, 7, 3], // +y
        [0, 2, 3, 1], // -z
        [4, 5, 7, 6], // +z
    ];
    let indices: Vec<u16> =
        faces.iter().flat_map(|q| [q[0], q[1], q[2], q[0], q[2], q[3]]).collect();
    let mut bytes: Vec<u8> = positions.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let index_start = bytes.len();
    bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    let (min, max) = (corner(0), corner(7));
    // The half-plane: 4 corners and 2 triangles, counter-clockwise seen from above.
    let plane_start = bytes.len();
    let plane: [[f32; 3]; 4] =
        [[0.0, -1.0, -20.0], [20.0, -1.0, -20.0], [20.0, -1.0, 20.0], [0.0, -1.0, 20.0]];
    bytes.extend(plane.iter().flatten().flat_map(|v| v.to_le_bytes()));
    bytes.extend([0u16, 2, 1, 0, 3, 2].iter().flat_map(|v| v.to_le_bytes()));
    let half_turn = (tilt / 2.0).sin_cos();
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": if edge { vec![0, 1, 2] } else { vec![0, 1] }}],
        "nodes": [
            {"mesh": 0, "rotation": [0.0, 0.0, half_turn.0, half_turn.1]},
            {"camera": 0, "translation": [0.0, camera_y, 0.0],
             "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]},
            {"mesh": 1}
        ],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": view, "ymag": view, "znear": 0.01, "zfar": 100.0}}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 2}, "indices": 3, "material": 1}]}
        ],
        "materials": [material, {
            "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0},
            "emissiveFactor": [1.0, 1.0, 1.0],
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
        }],
        "extensionsUsed": ["KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_ior", "KHR_materials_specular"],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": min, "max": max},
            {"bufferView": 1, "componentType": 5123, "count": 36, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0.0, -1.0, -20.0], "max": [20.0, -1.0, 20.0]},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": index_start},
            {"buffer": 0, "byteOffset": index_start, "byteLength": 72},
            {"buffer": 0, "byteOffset": plane_start, "byteLength": 48},
            {"buffer": 0, "byteOffset": plane_start + 48, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir = std::env::temp_dir().join(format!("renderfarm-glass-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("box.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// The furnace box: `box_scene` of half sizes (0.6, 0.4, 0.5) off-centre in the view, at an
/// angle that sends light through its sides.
pub fn furnace_box(tag: &str, material: serde_json::Value) -> std::path::PathBuf {
    box_scene(tag, [0.6, 0.4, 0.5], [0.1, 0.0, -0.2], material, 3.0, 1.0, 0.0, false)
}

/// Rewrites the glTF at `path` (a `box_scene`) to see through a perspective camera of vertical
/// field of view `yfov` radians from the same place, so that light paths can reach it.
pub fn with_perspective_camera(path: &Path, yfov: f64) {
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    json["cameras"][0] = serde_json::json!({
        "type": "perspective",
        "perspective": {"yfov": yfov, "aspectRatio": 1.0, "znear": 0.01}
    });
    std::fs::write(path, serde_json::to_string(&json).unwrap()).unwrap();
}

/// Bidirectional path tracing of frame 0 (the settings' integrator set to `bdpt`, their
/// environment map decoded as `map`): the camera tasks' film and the light tasks' film (two, as
/// the farm splits them); the image is their sum (`bdpt_sum`).
pub fn render_bdpt_with(
    scene: &common::scene::Scene,
    settings: &RenderSettings,
    map: Option<&common::envmap::EnvMap>,
) -> (Film, Film) {
    let settings =
        RenderSettings { integrator: common::settings::Integrator::Bdpt, ..settings.clone() };
    let prepared = prepare_frame(scene, &settings, map, 0).expect("prepare");
    let camera = render_prepared(&prepared, &settings);
    let rect = Rect { x0: 0, y0: 0, width: settings.width, height: settings.height };
    let mut light = Film::new(settings.width, settings.height);
    // Two light tasks, as the farm splits them: the light tile has `bdpt.light_paths` samples
    // per pixel sample.
    let n = settings.spp * settings.light_paths();
    let half = n / 2;
    for samples in [SampleRange { start: 0, end: half }, SampleRange { start: half, end: n }] {
        let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Light };
        light.merge_tile(&render_task(&prepared, settings.seed, &task).tile);
    }
    (camera, light)
}

/// Per pixel and channel: the sum of the two films' means and of their variances of the mean.
pub fn bdpt_sum(camera: &Film, light: &Film) -> Vec<([f64; 3], [f64; 3])> {
    camera
        .pixels
        .iter()
        .zip(&light.pixels)
        .map(|(c, l)| {
            let (mc, ml, vc, vl) = (c.mean(), l.mean(), c.variance_of_mean(), l.variance_of_mean());
            ([0, 1, 2].map(|i| mc[i] + ml[i]), [0, 1, 2].map(|i| vc[i] + vl[i]))
        })
        .collect()
}

/// The mean over the image of `bdpt_sum`, per channel, with its standard error.
pub fn bdpt_image_mean(camera: &Film, light: &Film) -> [(f64, f64); 3] {
    let sum = bdpt_sum(camera, light);
    let n = sum.len() as f64;
    [0, 1, 2].map(|c| {
        let mean = sum.iter().map(|p| p.0[c]).sum::<f64>() / n;
        (mean, (sum.iter().map(|p| p.1[c]).sum::<f64>() / (n * n)).sqrt())
    })
}

/// Photon mapping of frame 0 (the settings' integrator set to `sppm`, their environment map
/// decoded as `map`) in tasks of `per_task` passes on `threads` threads, as the farm splits it
/// (the frame is one tile).
pub fn render_sppm_with(
    scene: &Scene,
    settings: &RenderSettings,
    per_task: u32,
    threads: usize,
    map: Option<&common::envmap::EnvMap>,
) -> Film {
    let settings =
        RenderSettings { integrator: common::settings::Integrator::Sppm, ..settings.clone() };
    let prepared = prepare_frame(scene, &settings, map, 0).expect("prepare");
    let rect = Rect { x0: 0, y0: 0, width: settings.width, height: settings.height };
    let mut film = Film::new(settings.width, settings.height);
    let mut start = 0;
    while start < settings.spp {
        let samples = SampleRange { start, end: (start + per_task).min(settings.spp) };
        let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
        film.merge_tile(&render_task_threads(&prepared, settings.seed, &task, threads).tile);
        start = samples.end;
    }
    film
}

/// Appends to a glTF document the tinted, absorbing "water" of index 1 (its surface bends
/// nothing, but no shadow ray crosses it) and the extensions it uses; returns its material index.
pub fn push_water(j: &mut serde_json::Value) -> usize {
    let materials = j["materials"].as_array_mut().unwrap();
    materials.push(dielectric_material(1.0, 1.0, Some(([0.5, 0.7, 0.9], 0.3))));
    let material = materials.len() - 1;
    let used = j["extensionsUsed"].as_array_mut().unwrap();
    for e in ["KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_ior"] {
        if !used.iter().any(|u| u == e) {
            used.push(serde_json::json!(e));
        }
    }
    material
}

/// The Cornell box with the short block and the floor around it under "water": a box of an
/// absorbing, tinted medium of index 1 (its surface bends nothing, but no shadow ray crosses it)
/// 1.8 times the short block's size around it, reaching below the floor, so that paths inside
/// meet diffuse surfaces (the floor, the block, the red wall) and connections between them run
/// through the medium.
pub fn cornell_under_water() -> Scene {
    let path = edited_scene("cornell-box", "water", |j| {
        push_water_round_the_block(j);
    });
    common::gltf::load_path(&path).unwrap()
}

/// `cornell_under_water` with the water rough (roughness 0.3) and a point light in it, above the
/// short block, so that shadow rays run through the medium: from the surfaces inside and from
/// the rough surface into it.
pub fn cornell_under_rough_water_with_a_lamp() -> Scene {
    let path = edited_scene("cornell-box", "water-lamp", |j| {
        let (material, lo, hi) = push_water_round_the_block(j);
        j["materials"][material]["pbrMetallicRoughness"]["roughnessFactor"] =
            serde_json::json!(0.3);
        let at: Vec<f64> = (0..3)
            .map(|i| if i == 1 { hi[1] + 0.2 * (hi[1] - lo[1]) } else { 0.5 * (lo[i] + hi[i]) })
            .collect();
        j["extensionsUsed"].as_array_mut().unwrap().push(serde_json::json!("KHR_lights_punctual"));
        j["extensions"] = serde_json::json!({"KHR_lights_punctual": {"lights": [
            {"type": "point", "intensity": 0.5, "color": [1.0, 0.9, 0.8]}
        ]}});
        let nodes = j["nodes"].as_array_mut().unwrap();
        nodes.push(serde_json::json!({"translation": at, "extensions": {"KHR_lights_punctual": {"light": 0}}}));
        let node = nodes.len() - 1;
        j["scenes"][0]["nodes"].as_array_mut().unwrap().push(serde_json::json!(node));
    });
    common::gltf::load_path(&path).unwrap()
}

/// `cornell_under_water` with the short block, inside the water, unlit and textured: a 4 x 4
/// texture of colours over coordinates that differ at each of the block's corners, so that the
/// colour a path ends with inside the medium comes from the texture.
pub fn cornell_with_a_textured_unlit_block_under_water() -> Scene {
    let path = edited_scene("cornell-box", "water-unlit", |j| {
        push_water_round_the_block(j);
        let texels: Vec<u8> = (0..48u32).map(|k| (k * 37 % 251) as u8).collect();
        let png = rgb_png(4, 4, &texels);
        j["images"] =
            serde_json::json!([{"uri": format!("data:image/png;base64,{}", base64(&png))}]);
        j["textures"] = serde_json::json!([{"source": 0}]);
        let materials = j["materials"].as_array_mut().unwrap();
        materials.push(serde_json::json!({
            "name": "flat, textured",
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.8, 0.6, 1.0], "baseColorTexture": {"index": 0}},
            "extensions": {"KHR_materials_unlit": {}}
        }));
        let material = materials.len() - 1;
        // Each of the block's 20 corners its own coordinates, in a buffer of their own.
        let uv: Vec<u8> = (0..20u32)
            .flat_map(|k| [(k % 5) as f32 / 4.0, (k / 5) as f32 / 3.0])
            .flat_map(f32::to_le_bytes)
            .collect();
        let buffers = j["buffers"].as_array_mut().unwrap();
        buffers.push(serde_json::json!({"byteLength": uv.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&uv))}));
        let buffer = buffers.len() - 1;
        let views = j["bufferViews"].as_array_mut().unwrap();
        views.push(serde_json::json!({"buffer": buffer, "byteLength": uv.len()}));
        let view = views.len() - 1;
        let accessors = j["accessors"].as_array_mut().unwrap();
        accessors.push(serde_json::json!({"bufferView": view, "componentType": 5126, "count": 20, "type": "VEC2"}));
        let accessor = accessors.len() - 1;
        let block = &mut j["meshes"][3]["primitives"][0];
        block["attributes"]["TEXCOORD_0"] = serde_json::json!(accessor);
        block["material"] = serde_json::json!(material);
        j["extensionsUsed"].as_array_mut().unwrap().push(serde_json::json!("KHR_materials_unlit"));
    });
    common::gltf::load_path(&path).unwrap()
}

/// Puts the water of `cornell_under_water` round the Cornell box's short block; returns its
/// material and the block's corners.
fn push_water_round_the_block(j: &mut serde_json::Value) -> (usize, [f64; 3], [f64; 3]) {
    let material = push_water(j);
    let block = j["meshes"][3]["primitives"][0].clone();
    let (lo, hi) = {
        let a = &j["accessors"][block["attributes"]["POSITION"].as_u64().unwrap() as usize];
        let v = |k: &str| -> [f64; 3] { std::array::from_fn(|i| a[k][i].as_f64().unwrap()) };
        (v("min"), v("max"))
    };
    let mut primitive = block;
    primitive["material"] = serde_json::json!(material);
    let meshes = j["meshes"].as_array_mut().unwrap();
    meshes.push(serde_json::json!({"name": "water", "primitives": [primitive]}));
    let mesh = meshes.len() - 1;
    let s = 1.8;
    let t: Vec<f64> = (0..3).map(|i| 0.5 * (lo[i] + hi[i]) * (1.0 - s)).collect();
    let nodes = j["nodes"].as_array_mut().unwrap();
    nodes.push(
        serde_json::json!({"name": "water", "mesh": mesh, "translation": t, "scale": [s, s, s]}),
    );
    let node = nodes.len() - 1;
    j["scenes"][0]["nodes"].as_array_mut().unwrap().push(serde_json::json!(node));
    (material, lo, hi)
}

/// Appends to a glTF document an axis-aligned box from `lo` to `hi` of material `material`, a
/// closed mesh wound outward (its buffer in a `data:` URI), placed at the default scene's root.
pub fn push_box(j: &mut serde_json::Value, lo: [f32; 3], hi: [f32; 3], material: usize) {
    let corner = |i: usize| -> [f32; 3] {
        std::array::from_fn(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] })
    };
    let mut indices: Vec<u16> = Vec::new();
    for axis in 0..3 {
        let (a, b) = (1 << ((axis + 1) % 3), 1 << ((axis + 2) % 3));
        for high in [false, true] {
            let base = if high { 1 << axis } else { 0 };
            // (c1 - c0) x (c3 - c0) is +axis: outward on the high face, reversed on the low one.
            let q = [base, base | a, base | a | b, base | b];
            let q = if high { q } else { [q[0], q[3], q[2], q[1]] };
            indices.extend([q[0], q[1], q[2], q[0], q[2], q[3]].map(|i| i as u16));
        }
    }
    let mut bytes: Vec<u8> = (0..8).flat_map(corner).flat_map(f32::to_le_bytes).collect();
    bytes.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    let uri = format!("data:application/octet-stream;base64,{}", base64(&bytes));
    let push = |j: &mut serde_json::Value, key: &str, v: serde_json::Value| -> usize {
        let a = j[key].as_array_mut().unwrap();
        a.push(v);
        a.len() - 1
    };
    let buffer = push(j, "buffers", serde_json::json!({"byteLength": bytes.len(), "uri": uri}));
    let positions = push(
        j,
        "bufferViews",
        serde_json::json!({"buffer": buffer, "byteOffset": 0, "byteLength": 96}),
    );
    let index_view = push(
        j,
        "bufferViews",
        serde_json::json!({"buffer": buffer, "byteOffset": 96, "byteLength": 72}),
    );
    let position = push(
        j,
        "accessors",
        serde_json::json!({"bufferView": positions, "componentType": 5126, "count": 8, "type": "VEC3", "min": lo, "max": hi}),
    );
    let index = push(
        j,
        "accessors",
        serde_json::json!({"bufferView": index_view, "componentType": 5123, "count": 36, "type": "SCALAR"}),
    );
    let mesh = push(
        j,
        "meshes",
        serde_json::json!({"name": "box", "primitives": [{"attributes": {"POSITION": position}, "indices": index, "material": material}]}),
    );
    let node = push(j, "nodes", serde_json::json!({"name": "box", "mesh": mesh}));
    let scene = j["scene"].as_u64().unwrap_or(0) as usize;
    j["scenes"][scene]["nodes"].as_array_mut().unwrap().push(serde_json::json!(node));
}

/// The Cornell box with its light inside "water": a box of an absorbing, tinted medium of index
/// 1 around the ceiling's light, from 0.1 below it to past the ceiling, so that every light
/// subpath and photon starts inside the medium and loses light to it on its way out.
pub fn cornell_light_in_water() -> Scene {
    let path = edited_scene("cornell-box", "light-water", |j| {
        let material = push_water(j);
        push_box(j, [0.17, 0.45, 0.18], [0.39, 0.6, 0.38], material);
    });
    common::gltf::load_path(&path).unwrap()
}

/// `cornell_motion` (a still camera) with its light sliding within the shutter as the short
/// block does (`with_moving_light`) inside "water": a box of an absorbing, tinted medium of
/// index 1 around the light's whole slide, from 0.1 below it to past the ceiling, so that every
/// photon from the moving light starts inside the medium.
pub fn cornell_moving_light_in_water() -> (Scene, RenderSettings) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let (_, settings) = cornell_motion(false);
    let mut j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("cornell-motion.gltf")).unwrap())
            .unwrap();
    let material = push_water(&mut j);
    push_box(&mut j, [0.15, 0.45, 0.18], [0.47, 0.6, 0.38], material);
    let out = std::env::temp_dir().join(format!("renderfarm-moving-water-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::copy(dir.join("cornell-box.bin"), out.join("cornell-box.bin")).unwrap();
    let path = out.join("cornell-motion-water.gltf");
    std::fs::write(&path, serde_json::to_string(&j).unwrap()).unwrap();
    (with_moving_light(&common::gltf::load_path(&path).unwrap()), settings)
}

/// The many-lights scene of `n` small emitters over a floor
/// (`worker::test_scenes::many_lights_gltf`), written to a temporary file and loaded.
pub fn load_many_lights(n: usize, tag: &str) -> Scene {
    let dir = std::env::temp_dir().join(format!("renderfarm-{tag}-many-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("many-{n}.gltf"));
    std::fs::write(&path, worker::test_scenes::many_lights_gltf(n)).unwrap();
    common::gltf::load_path(&path).unwrap()
}

/// Loads a scene of the repository's `scenes/` folder (`name` with its extension).
pub fn repo_scene(name: &str) -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes").join(name);
    common::gltf::load_path(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// An 8-bit greyscale PNG of `width` x `height` texels (`texels` row by row, the top row
/// first), uncompressed (one stored deflate block: at most 65,535 bytes of scanlines).
pub fn grey_png(width: u32, height: u32, texels: &[u8]) -> Vec<u8> {
    png_of(width, height, 1, texels)
}

/// An 8-bit RGB PNG of `width` x `height` texels (`texels` three bytes each), as [`grey_png`].
pub fn rgb_png(width: u32, height: u32, texels: &[u8]) -> Vec<u8> {
    png_of(width, height, 3, texels)
}

/// An 8-bit PNG of one (grey) or three (RGB) channels, as [`grey_png`].
fn png_of(width: u32, height: u32, channels: u32, texels: &[u8]) -> Vec<u8> {
    fn crc(data: &[u8]) -> u32 {
        let mut c = 0xffff_ffffu32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
            }
        }
        !c
    }
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend((data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend(data);
        out.extend(&body);
        out.extend(crc(&body).to_be_bytes());
    }
    assert_eq!(texels.len(), (width * height * channels) as usize);
    // Raw scanlines (filter byte 0) in a stored (uncompressed) zlib stream.
    let raw: Vec<u8> = texels
        .chunks((width * channels) as usize)
        .flat_map(|row| std::iter::once(0).chain(row.iter().copied()))
        .collect();
    let len = u16::try_from(raw.len()).expect("one stored block");
    let mut zlib = vec![0x78, 0x01, 0x01];
    zlib.extend(len.to_le_bytes());
    zlib.extend((!len).to_le_bytes());
    zlib.extend(&raw);
    let (mut a, mut b) = (1u32, 0u32);
    for &x in &raw {
        a = (a + x as u32) % 65521;
        b = (b + a) % 65521;
    }
    zlib.extend(((b << 16) | a).to_be_bytes());
    let mut png = vec![0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];
    let mut ihdr = Vec::new();
    ihdr.extend(width.to_be_bytes());
    ihdr.extend(height.to_be_bytes());
    // 8 bits, colour type 0 (greyscale) or 2 (RGB).
    ihdr.extend([8, if channels == 3 { 2 } else { 0 }, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", &zlib);
    chunk(&mut png, b"IEND", &[]);
    png
}

/// A glTF document of the square of half size `half` (`square_geometry`) in material
/// `material`, seen by `camera` (a glTF camera) two units above its centre, looking down.
pub fn square_seen_from_above(
    half: f32,
    camera: serde_json::Value,
    material: serde_json::Value,
) -> serde_json::Value {
    let mut doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "plane", "mesh": 0},
            // Looking down -y: rotate -90 degrees about x.
            {"name": "camera", "camera": 0, "translation": [0.0, 2.0, 0.0],
             "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}
        ],
        "cameras": [camera],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [material]
    });
    for (key, value) in square_geometry(half).as_object().unwrap() {
        doc[key] = value.clone();
    }
    doc
}

/// A square of half size `half` in the plane y = 0 (normal +y), texture coordinates 0 to 1
/// over it: the glTF `accessors` (0: POSITION, 1: TEXCOORD_0, 2: indices), `bufferViews` and
/// `buffers` of a document whose mesh reads them.
pub fn square_geometry(half: f32) -> serde_json::Value {
    let h = half;
    let positions: [[f32; 3]; 4] = [[-h, 0.0, -h], [h, 0.0, -h], [h, 0.0, h], [-h, 0.0, h]];
    let uvs: [[f32; 2]; 4] = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let indices: [u16; 6] = [0, 2, 1, 0, 3, 2];
    let mut bytes: Vec<u8> = positions.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend(uvs.iter().flatten().flat_map(|v| v.to_le_bytes()));
    bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    serde_json::json!({
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-h, 0.0, -h], "max": [h, 0.0, h]},
            {"bufferView": 0, "byteOffset": 48, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 80},
            {"buffer": 0, "byteOffset": 80, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    })
}

/// Asserts that the wavefront renders `scene` under `settings` exactly as the scalar path tracer
/// does: the same sums bit for bit and the same ray count, on the whole frame and on an offset
/// tile with an offset sample range (`assert_same_sums`). Panics if the wavefront does not take
/// the scene.
pub fn assert_wavefront_renders_the_scalar_paths(
    name: &str,
    scene: &Scene,
    settings: &RenderSettings,
) {
    let wavefront_scene = prepare(scene, settings).expect("prepare");
    let mut scalar = prepare(scene, settings).expect("prepare");
    scalar.drop_wavefront();
    let (w, h, spp) = (settings.width, settings.height, settings.spp);
    for (rect, samples) in [
        (Rect { x0: 0, y0: 0, width: w, height: h }, SampleRange { start: 0, end: spp }),
        (
            Rect { x0: w / 4, y0: h / 5, width: w / 2, height: h / 2 },
            SampleRange { start: spp / 2, end: spp + spp / 2 },
        ),
    ] {
        let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
        assert_same_sums(name, &wavefront_scene, &scalar, &task, &[4, 8, 16]);
    }
}

/// Asserts that `wavefront` (a preparation the wavefront takes) renders `task` as `scalar` (the
/// same scene without the wavefront's tables) does: the same sums bit for bit and the same ray
/// count at this CPU's lane count, and at each of `lanes` emulated (so that 16 lanes are checked
/// on any CPU) on every other row, as the second of two threads renders them.
pub fn assert_same_sums(
    name: &str,
    wavefront: &PreparedScene,
    scalar: &PreparedScene,
    task: &TaskSpec,
    lanes: &[usize],
) {
    use worker::render::{integrators::wavefront as kernel, render_rows_scalar};
    let tables =
        wavefront.wavefront().unwrap_or_else(|| panic!("{name}: the wavefront does not apply"));
    let rect = task.rect;
    let (a, b) = (render_task(wavefront, 11, task), render_task(scalar, 11, task));
    assert!(a.rays > 0);
    assert_eq!(a.rays, b.rays, "{name} {rect:?}: rays");
    for (i, (pa, pb)) in a.tile.pixels.iter().zip(&b.tile.pixels).enumerate() {
        assert_eq!(pa, pb, "{name} {rect:?}: pixel {i}");
    }
    let (want, want_stats) = render_rows_scalar(scalar, 11, task, 1, 2);
    for &n in lanes {
        let (got, stats) = kernel::render_rows_portable(wavefront, tables, 11, task, (1, 2), n)
            .expect("a lane count it has");
        assert_eq!(stats.rays, want_stats.rays, "{name} {rect:?} {n} lanes: rays");
        assert!(got == want, "{name} {rect:?}: {n} lanes differ");
    }
}
