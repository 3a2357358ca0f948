//! Structure-aware fuzzing on stable Rust (proptest): the inputs a hostile client controls, each
//! mutated from valid seeds, never panic and stay within their budgets.
//! - the glTF loader, seeded with the glTF-Validator suite (`tests/assets/invalid/`): byte
//!   flips, truncations, deletions and repeats, and JSON-aware mutations (a value replaced by an
//!   absurd one, a key dropped, an array element repeated);
//! - the bundle reader, on mutated zips of a real scene;
//! - the settings parser, on JSON built from its own keys with absurd values;
//! - the result decoder, on mutated encodings of a real result.
//!
//! Each property runs `RENDERFARM_FUZZ_CASES` cases (default 200); a longer run:
//! `RENDERFARM_FUZZ_CASES=20000 cargo test --release -p common --test fuzz`. A failure is shrunk
//! and its seed written to `fuzz.proptest-regressions` beside this file, which is committed so
//! that every later run replays it first.

use std::{
    path::{Path, PathBuf},
    sync::OnceLock,
};

use common::{
    budget::SceneBudget,
    bundle::Bundle,
    film::{Rect, TileAccum},
    gltf::{load_slice_within, DirResolver},
    protocol::{decode_result, encode_result, SampleRange, TaskKind, TaskResult, TaskSpec},
    settings::RenderSettings,
};
use proptest::{prelude::*, test_runner::FileFailurePersistence};
use serde_json::{json, Value};

/// Small budgets, so that a mutated header cannot make a case allocate much.
fn budget() -> SceneBudget {
    SceneBudget { inflated_bytes: 64 << 20, entries: 1000, texels: 1 << 20, triangles: 1 << 20 }
}

fn cases() -> u32 {
    std::env::var("RENDERFARM_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(200)
}

/// The repository's `tests/assets/`: the glTF-Validator suite and the Khronos sample assets.
fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets")
}

/// The validator suite's `.gltf` and `.glb` files: (folder, bytes).
fn corpus() -> &'static [(PathBuf, Vec<u8>)] {
    static CORPUS: OnceLock<Vec<(PathBuf, Vec<u8>)>> = OnceLock::new();
    CORPUS.get_or_init(|| {
        let mut files = Vec::new();
        let mut stack = vec![assets().join("invalid/validator-tests/test")];
        while let Some(dir) = stack.pop() {
            for entry in std::fs::read_dir(&dir).expect("the validator suite in tests/assets") {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    stack.push(path);
                } else if path.extension().is_some_and(|e| e == "gltf" || e == "glb") {
                    files.push((dir.clone(), std::fs::read(&path).unwrap()));
                }
            }
        }
        files.sort();
        assert!(files.len() >= 300, "the validator suite has {} scene files", files.len());
        files
    })
}

/// A byte-level mutation.
#[derive(Clone, Debug)]
enum Bytes {
    Flip { at: usize, bit: u8 },
    Set { at: usize, value: u8 },
    Truncate { at: usize },
    Delete { at: usize, len: usize },
    Repeat { at: usize, len: usize },
}

fn bytes_mutation() -> impl Strategy<Value = Bytes> {
    prop_oneof![
        (any::<usize>(), 0u8..8).prop_map(|(at, bit)| Bytes::Flip { at, bit }),
        (any::<usize>(), prop_oneof![Just(0u8), Just(0xff), Just(0x7f), Just(0x80), any::<u8>()])
            .prop_map(|(at, value)| Bytes::Set { at, value }),
        any::<usize>().prop_map(|at| Bytes::Truncate { at }),
        (any::<usize>(), 1usize..64).prop_map(|(at, len)| Bytes::Delete { at, len }),
        (any::<usize>(), 1usize..64).prop_map(|(at, len)| Bytes::Repeat { at, len }),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Bytes) {
    if bytes.is_empty() {
        return;
    }
    let n = bytes.len();
    match *m {
        Bytes::Flip { at, bit } => bytes[at % n] ^= 1 << bit,
        Bytes::Set { at, value } => bytes[at % n] = value,
        Bytes::Truncate { at } => bytes.truncate(at % n),
        Bytes::Delete { at, len } => {
            let at = at % n;
            bytes.drain(at..(at + len).min(n));
        }
        Bytes::Repeat { at, len } => {
            let at = at % n;
            let piece: Vec<u8> = bytes[at..(at + len).min(n)].to_vec();
            bytes.splice(at..at, piece);
        }
    }
}

/// A JSON-level mutation: the `k`-th value below the root (pre-order) becomes `with`, or, for
/// `None`, is dropped from its object or repeated in its array.
#[derive(Clone, Debug)]
struct JsonEdit {
    k: usize,
    with: Option<Value>,
}

fn absurd_value() -> impl Strategy<Value = Option<Value>> {
    prop_oneof![
        Just(None),
        Just(Some(json!(-1))),
        Just(Some(json!(0))),
        Just(Some(json!(4294967295u64))),
        Just(Some(json!(18446744073709551615u64))),
        Just(Some(json!(1e308))),
        Just(Some(json!(-1e308))),
        Just(Some(json!(0.5))),
        Just(Some(json!("x"))),
        Just(Some(json!("data:application/octet-stream;base64,AAAA"))),
        Just(Some(json!([]))),
        Just(Some(json!({}))),
        Just(Some(Value::Null)),
        Just(Some(json!(true))),
        Just(Some(json!([0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]))),
    ]
}

fn json_edit() -> impl Strategy<Value = JsonEdit> {
    (any::<usize>(), absurd_value()).prop_map(|(k, with)| JsonEdit { k, with })
}

/// Counts the values below `v` in pre-order.
fn count(v: &Value) -> usize {
    match v {
        Value::Array(a) => a.iter().map(|c| 1 + count(c)).sum(),
        Value::Object(o) => o.values().map(|c| 1 + count(c)).sum(),
        _ => 0,
    }
}

/// Applies `with` to the `k`-th value below `v`; true once done.
fn edit(v: &mut Value, k: &mut usize, with: &Option<Value>) -> bool {
    let keys: Vec<String> = match v {
        Value::Object(o) => o.keys().cloned().collect(),
        Value::Array(a) => (0..a.len()).map(|i| i.to_string()).collect(),
        _ => return false,
    };
    for key in keys {
        if *k == 0 {
            match (v, with) {
                (Value::Object(o), None) => {
                    o.remove(&key);
                }
                (Value::Array(a), None) => {
                    let i: usize = key.parse().unwrap();
                    let repeated = a[i].clone();
                    a.insert(i, repeated);
                }
                (Value::Object(o), Some(w)) => {
                    o.insert(key, w.clone());
                }
                (Value::Array(a), Some(w)) => a[key.parse::<usize>().unwrap()] = w.clone(),
                _ => unreachable!("keys come from an object or an array"),
            }
            return true;
        }
        *k -= 1;
        let child = match v {
            Value::Object(o) => o.get_mut(&key).unwrap(),
            Value::Array(a) => &mut a[key.parse::<usize>().unwrap()],
            _ => unreachable!("keys come from an object or an array"),
        };
        if edit(child, k, with) {
            return true;
        }
    }
    false
}

/// A real result's encoding, for the decoder's seeds.
fn encoded_result(spec: TaskSpec) -> Vec<u8> {
    let mut tile = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                tile.add_sample(x, y, s, [0.5 + s as f32, 0.25, 1.0]);
            }
        }
    }
    encode_result(&TaskResult { spec, tile, rays: 7, kernel: "path, scalar".into() })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        failure_persistence: Some(Box::new(FileFailurePersistence::WithSource("proptest-regressions"))),
        ..ProptestConfig::default()
    })]

    #[test]
    fn the_gltf_loader_never_panics_on_mutated_files(
        file in any::<prop::sample::Index>(),
        json_edits in prop::collection::vec(json_edit(), 0..4),
        byte_edits in prop::collection::vec(bytes_mutation(), 0..4),
    ) {
        let (dir, seed) = file.get(corpus());
        let mut bytes = seed.clone();
        if let Ok(mut doc) = serde_json::from_slice::<Value>(&bytes) {
            for e in &json_edits {
                let mut k = e.k % count(&doc).max(1);
                edit(&mut doc, &mut k, &e.with);
            }
            bytes = doc.to_string().into_bytes();
        }
        for m in &byte_edits {
            apply(&mut bytes, m);
        }
        let _ = load_slice_within(&bytes, &DirResolver::new(dir), &budget());
    }

    #[test]
    fn the_bundle_reader_never_panics_on_mutated_zips(
        edits in prop::collection::vec(bytes_mutation(), 1..6),
    ) {
        static ZIP: OnceLock<Vec<u8>> = OnceLock::new();
        let zip = ZIP.get_or_init(|| {
            let dir = assets().join("real/BoxTextured/glTF");
            let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
                .unwrap()
                .map(|e| e.unwrap().path())
                .map(|p| {
                    let name = p.file_name().unwrap().to_string_lossy().into_owned();
                    (name, std::fs::read(&p).unwrap())
                })
                .collect();
            files.sort();
            Bundle::pack(&files).unwrap()
        });
        let mut bytes = zip.clone();
        for m in &edits {
            apply(&mut bytes, m);
        }
        if let Ok(bundle) = Bundle::open(&bytes, &budget()) {
            let _ = bundle.load_scene();
        }
    }

    #[test]
    fn the_settings_parser_never_panics_and_what_it_takes_is_valid(
        keys in prop::collection::vec((0usize..16, absurd_value()), 0..8),
        nested in prop::collection::vec((0usize..12, absurd_value()), 0..4),
    ) {
        const TOP: [&str; 16] = [
            "width", "height", "spp", "target_rel_error", "time_limit_s", "max_depth", "seed",
            "camera", "lens", "shutter", "frames", "environment", "tile_size",
            "samples_per_task", "sp", "integrator",
        ];
        const INNER: [(&str, &str); 12] = [
            ("lens", "aperture_radius"), ("lens", "focus_distance"), ("shutter", "open"),
            ("shutter", "close"), ("frames", "start"), ("frames", "end"), ("frames", "fps"),
            ("environment", "color"), ("environment", "map"), ("environment", "intensity"),
            ("environment", "rotation_deg"), ("environment", "visible"),
        ];
        let mut doc = json!({});
        for (k, v) in &keys {
            if let Some(v) = v {
                doc[TOP[*k]] = v.clone();
            }
        }
        for (k, v) in &nested {
            let (outer, inner) = INNER[*k];
            if !doc[outer].is_object() {
                doc[outer] = json!({});
            }
            if let Some(v) = v {
                doc[outer][inner] = v.clone();
            }
        }
        if let Ok(settings) = RenderSettings::from_json(&doc.to_string()) {
            prop_assert!(settings.validate().is_ok());
            let again = RenderSettings::from_json(&serde_json::to_string(&settings).unwrap());
            prop_assert_eq!(again.ok(), Some(settings));
        }
    }

    #[test]
    fn the_result_decoder_never_panics_on_mutated_results(
        edits in prop::collection::vec(bytes_mutation(), 1..6),
    ) {
        let spec = TaskSpec {
            frame: 0,
            rect: Rect { x0: 0, y0: 0, width: 4, height: 3 },
            samples: SampleRange { start: 0, end: 4 },
            kind: TaskKind::Camera,
        };
        let mut bytes = encoded_result(spec);
        for m in &edits {
            apply(&mut bytes, m);
        }
        if let Ok(result) = decode_result(&bytes) {
            let _ = result.check_answers(&spec);
        }
    }
}
