//! Small hostile scenes against `coordinator serve` (the real binary, loopback): a zip that
//! inflates far past its size, an image whose header asks for more texels than the budget, a few
//! bytes of instancing that describe millions of triangles. Each is refused from what it
//! declares, before the work, with a message naming the budget, its setting and the figure; the
//! coordinator's peak memory stays small, and it serves the next request.

use base64::Engine as _;
use serde_json::{json, Value};
use tests::*;

/// Uploads `bytes`; returns (status, error message).
fn upload_raw(url: &str, bytes: &[u8]) -> (u16, String) {
    let a = post_bytes(&format!("{url}/api/v1/scenes"), "application/octet-stream", &[], bytes);
    (a.status, a.error())
}

/// One triangle, placed by `EXT_mesh_gpu_instancing` at `instances` positions, and textured
/// by `image` (a PNG) through `textures` textures, all in one `.gltf` with data URIs.
fn scene(instances: usize, image: Option<&[u8]>, textures: usize) -> Vec<u8> {
    let b64 = |b: &[u8]| base64::engine::general_purpose::STANDARD.encode(b);
    let positions: Vec<u8> =
        [0f32, 0., 0., 1., 0., 0., 0., 1., 0.].iter().flat_map(|v| v.to_le_bytes()).collect();
    let offsets: Vec<u8> =
        (0..instances).flat_map(|i| [i as f32, 0., 0.]).flat_map(|v| v.to_le_bytes()).collect();
    let mut doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["EXT_mesh_gpu_instancing"],
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "extensions": {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": 1}}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [
            {"byteLength": positions.len(), "uri": format!("data:application/octet-stream;base64,{}", b64(&positions))},
            {"byteLength": offsets.len(), "uri": format!("data:application/octet-stream;base64,{}", b64(&offsets))}
        ],
        "bufferViews": [{"buffer": 0, "byteLength": positions.len()}, {"buffer": 1, "byteLength": offsets.len()}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": instances, "type": "VEC3"}
        ]
    });
    if let Some(png) = image {
        doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", b64(png))}]);
        doc["textures"] = Value::Array((0..textures).map(|_| json!({"source": 0})).collect());
        doc["materials"] = Value::Array(
            (0..textures)
                .map(|t| json!({"pbrMetallicRoughness": {"baseColorTexture": {"index": t}}}))
                .collect(),
        );
        doc["meshes"][0]["primitives"] = Value::Array(
            (0..textures).map(|m| json!({"attributes": {"POSITION": 0}, "material": m})).collect(),
        );
    }
    doc.to_string().into_bytes()
}

/// A 1x1 PNG whose header says `width` x `height` (its CRC made right): the size is what a
/// decoder would allocate for.
fn lying_png(width: u32, height: u32) -> Vec<u8> {
    let mut png = Vec::new();
    image::RgbaImage::from_raw(1, 1, vec![255; 4])
        .unwrap()
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    png[16..20].copy_from_slice(&width.to_be_bytes());
    png[20..24].copy_from_slice(&height.to_be_bytes());
    let crc = png[12..29].iter().fold(!0u32, |mut c, &b| {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
        c
    });
    png[29..33].copy_from_slice(&(!crc).to_be_bytes());
    png
}

#[test]
fn hostile_scenes_are_refused_before_the_work_in_bounded_memory() {
    let dir = temp_dir("budgets");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let args = ["--max-scene-mib", "16", "--max-megatriangles", "0.1"];
    let coordinator = start_coordinator(&dir.join("data"), port, &args);

    // 1. A zip of one member that inflates to 256 MiB from a few hundred kilobytes.
    let bomb = {
        use std::io::Write as _;
        let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        let deflated = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated)
            .large_file(false);
        w.start_file("scene.gltf", deflated).unwrap();
        let spaces = vec![b' '; 1 << 20];
        for _ in 0..256 {
            w.write_all(&spaces).unwrap();
        }
        w.finish().unwrap().into_inner()
    };
    assert!(bomb.len() < 1 << 20, "the bomb is {} bytes", bomb.len());
    let (status, error) = upload_raw(&url, &bomb);
    assert_eq!(status, 422, "{error}");
    assert!(
        error.contains("268.4 M bytes unpacked") && error.contains("--max-scene-mib"),
        "{error}"
    );

    // 2. One image whose header claims 16384 x 16384 texels (268 M, over the default 256 M),
    //    named by eight textures.
    let (status, error) = upload_raw(&url, &scene(1, Some(&lying_png(16384, 16384)), 8));
    assert_eq!(status, 422, "{error}");
    assert!(
        error.contains("268.4 M decoded texels") && error.contains("--max-megatexels"),
        "{error}"
    );

    // 3. 200,000 placements of one triangle, over the budget of 100,000 triangles: refused from
    //    the accessor's count, before the placements are read.
    let (status, error) = upload_raw(&url, &scene(200_000, None, 0));
    assert_eq!(status, 422, "{error}");
    assert!(
        error.contains("200.0 k triangles") && error.contains("--max-megatriangles"),
        "{error}"
    );

    // Within the budgets the same shapes are taken, and the service is healthy.
    let (status, error) = upload_raw(&url, &scene(1000, Some(&lying_png(1, 1)), 8));
    assert!(status == 201 || status == 200, "{status} {error}");
    assert_eq!(get(&format!("{url}/healthz")).status, 200);
    let peak = peak_mib(&coordinator);
    eprintln!("coordinator peak resident memory: {peak:.0} MiB");
    assert!(peak < 100.0, "the coordinator peaked at {peak:.0} MiB");
}

/// The width and height of a PNG, from its header.
fn png_size(png: &[u8]) -> (u32, u32) {
    assert_eq!(&png[1..4], b"PNG", "not a PNG");
    let be = |at: usize| u32::from_be_bytes(png[at..at + 4].try_into().unwrap());
    (be(16), be(20))
}

/// Frames far larger than the coordinator's memory budget, nothing rendered yet, are served
/// read a tile at a time: a 16384 x 16384 frame (the largest a job may ask for) as a PNG
/// downscaled to 2048 pixels a side, and an 8192 x 8192 one as its whole EXR (1.9 GB of
/// channels, written a row of tiles at a time and streamed). The coordinator's memory stays
/// bounded, and requests made meanwhile are answered at once (the farm's lock is held for one
/// tile's copy at a time, never for the frame).
#[test]
fn huge_frames_are_served_a_tile_at_a_time_in_bounded_memory() {
    use std::{
        io::Read as _,
        sync::{atomic::AtomicBool, atomic::Ordering::Relaxed, Arc},
        time::{Duration, Instant},
    };
    let dir = temp_dir("huge-frame");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let coordinator = start_coordinator(&dir.join("data"), port, &[]);
    let scene = upload(&url, &cornell_zip());
    let big = create_job(&url, &scene, &json!({"width": 16384, "height": 16384, "spp": 1}), 0);
    let side = 8192;
    let id = create_job(&url, &scene, &json!({"width": side, "height": side, "spp": 1}), 0);

    // Requests made while the frames are served: their slowest answer.
    let serving = Arc::new(AtomicBool::new(true));
    let watcher = {
        let (serving, status_url) = (serving.clone(), format!("{url}/api/v1/jobs/{id}"));
        std::thread::spawn(move || {
            let (mut slowest, mut answered) = (Duration::ZERO, 0);
            while serving.load(Relaxed) {
                let start = Instant::now();
                assert_eq!(get(&status_url).status, 200);
                slowest = slowest.max(start.elapsed());
                answered += 1;
                std::thread::sleep(Duration::from_millis(5));
            }
            (slowest, answered)
        })
    };

    let start = Instant::now();
    let png = get(&format!("{url}/api/v1/jobs/{big}/frames/0.png"));
    let png_time = start.elapsed();
    assert_eq!(png.status, 200, "{}", png.error());
    assert_eq!(png_size(&png.body), (2048, 2048), "downscaled 8 times");

    // The EXR is read as it comes: its header checked, the rest counted.
    let start = Instant::now();
    let response = ureq::get(&format!("{url}/api/v1/jobs/{id}/frames/0.exr")).call().unwrap();
    let declared: u64 = response.header("content-length").unwrap().parse().unwrap();
    let mut body = response.into_reader();
    let mut head = vec![0; 64 << 10];
    body.read_exact(&mut head).unwrap();
    let rest = std::io::copy(&mut body, &mut std::io::sink()).unwrap();
    let exr_time = start.elapsed();
    serving.store(false, Relaxed);
    let (slowest, answered) = watcher.join().unwrap();
    assert_eq!(head.len() as u64 + rest, declared, "the whole file came");
    let meta = coordinator::output::read_exr_meta(&head).unwrap();
    let size = meta.headers[0].layer_size;
    assert_eq!((size.width(), size.height()), (side as usize, side as usize));
    assert_eq!(meta.headers.len(), 2, "the image part and the variance part");

    let peak = peak_mib(&coordinator);
    eprintln!(
        "16384^2 frame: PNG in {png_time:.2?}; {side}^2 frame: EXR ({:.0} MB) in \
         {exr_time:.2?}; {answered} status requests meanwhile, the slowest {slowest:.2?}; \
         coordinator peak resident memory {peak:.0} MiB",
        declared as f64 / 1e6
    );
    // The 8192^2 frame's channels alone would be 1.9 GB; a band of 32 rows is 7 MB.
    assert!(peak < 300.0, "the coordinator peaked at {peak:.0} MiB");
    assert!(slowest < Duration::from_millis(500), "a request waited {slowest:.2?}");
    assert_eq!(get(&format!("{url}/healthz")).status, 200);
}
