//! Loads the repository's scenes (`scenes/`), the real sample assets and the whole glTF-Validator
//! test suite (`tests/assets/`).

use std::cell::RefCell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};

use super::*;

/// The repository's `scenes/`: the scenes made for the renderer.
fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

/// The repository's `tests/assets/`: the Khronos sample assets (`real/`) and the glTF-Validator
/// suite (`invalid/`), each with its licence.
fn assets_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets")
}

fn files_with_ext(dir: &Path, recursive: bool) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                if recursive {
                    stack.push(p);
                }
            } else if p.extension().is_some_and(|x| x == "gltf" || x == "glb") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn cornell_box_gltf_and_glb_agree() {
    let dir = scenes_dir();
    let a = load_path(&dir.join("cornell-box.gltf")).expect("cornell-box.gltf");
    let b = load_path(&dir.join("cornell-box.glb")).expect("cornell-box.glb");
    for s in [&a, &b] {
        check_renderable(s).expect("renderable");
        assert_eq!(s.triangle_count(), 32);
        assert_eq!(s.instances.len(), 6);
        assert_eq!(s.materials.len(), 4, "white, green, red, light; no default needed");
        for wall in ["white", "green", "red"] {
            let m = s.materials.iter().find(|m| m.name == wall).expect(wall);
            assert_eq!(m.specular, 0.0, "{wall}");
            assert_eq!(m.emissive, Vec3::ZERO, "{wall}");
            assert!(m.double_sided);
        }
        let light = s.materials.iter().find(|m| m.name == "light").expect("light material");
        let expect = Vec3::new(1.0, 0.760_716_8, 0.367_301_34) * 18.387;
        assert!((light.emissive - expect).abs().max_element() < 1e-5, "{:?}", light.emissive);
        assert!(!light.double_sided);
        assert_eq!(s.cameras.len(), 1);
        let cam = &s.cameras[0];
        assert_eq!(cam.name, "camera");
        assert!(
            (cam.position() - DVec3::new(0.278, 0.273, -0.8)).length() < 1e-12,
            "{:?}",
            cam.position()
        );
        // Rotated 180 degrees about y: looks down +z into the box.
        let view = cam.transform.transform_vector3(DVec3::NEG_Z);
        assert!((view - DVec3::Z).length() < 1e-9, "{view:?}");
        assert!(s.lights.is_empty());
    }
    assert_eq!(a.triangle_count(), b.triangle_count());
    for (ma, mb) in a.materials.iter().zip(&b.materials) {
        assert_eq!(format!("{ma:?}"), format!("{mb:?}"));
    }
    for (ma, mb) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(ma.positions, mb.positions);
        assert_eq!(ma.indices, mb.indices);
    }
}

#[test]
fn furnace_scenes_load() {
    let dir = scenes_dir();
    for (name, emissive) in [("furnace.gltf", 0.0), ("furnace-closed.gltf", 0.2)] {
        let s = load_path(&dir.join(name)).expect(name);
        check_renderable(&s).expect(name);
        assert_eq!(s.triangle_count(), 1280, "{name}");
        assert_eq!(s.meshes[0].positions.len(), 642);
        assert_eq!(s.materials.len(), 1);
        assert_eq!(s.materials[0].specular, 0.0);
        assert_eq!(s.materials[0].base_color.truncate(), Vec3::splat(0.8));
        assert_eq!(s.materials[0].emissive, Vec3::splat(emissive));
        assert_eq!(s.cameras.len(), 1);
    }
}

/// Every `.gltf`/`.glb` in the glTF/, glTF-Binary/ and glTF-Embedded/ folders of the real assets.
fn real_asset_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir.join("real")) else { return out };
    for asset in entries.flatten() {
        for variant in ["glTF", "glTF-Binary", "glTF-Embedded"] {
            out.extend(files_with_ext(&asset.path().join(variant), false));
        }
    }
    out.sort();
    out
}

#[test]
fn real_assets_load() {
    let dir = assets_dir();
    let files = real_asset_files(&dir);
    assert!(files.len() >= 35, "expected the real assets, found {}", files.len());
    let mut failures = Vec::new();
    for f in &files {
        match load_path(f) {
            Ok(s) => {
                if let Err(e) = check_renderable(&s) {
                    failures.push(format!("{}: {e}", f.display()));
                }
                for m in &s.meshes {
                    let n = m.positions.len();
                    assert!(
                        m.indices.iter().flatten().all(|&i| (i as usize) < n),
                        "{}",
                        f.display()
                    );
                    assert!(m.material < s.materials.len());
                }
                for mat in &s.materials {
                    for t in [
                        mat.base_color_texture,
                        mat.emissive_texture,
                        mat.metallic_roughness_texture,
                    ] {
                        assert!(t.is_none_or(|t| t.texture < s.textures.len()));
                    }
                }
            }
            Err(e) => failures.push(format!("{}: {e}", f.display())),
        }
    }
    println!("real assets: {} files, {} failed", files.len(), failures.len());
    assert!(failures.is_empty(), "failed:\n{}", failures.join("\n"));
    // The Draco variant (KHR_draco_mesh_compression) is compared with Box in
    // `tests_compression.rs`.
}

fn real(dir: &Path, rel: &str) -> Scene {
    load_path(&dir.join("real").join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

#[test]
fn real_assets_features() {
    let dir = assets_dir();
    // MeshPrimitiveModes: points, lines, line loop and line strip are skipped; triangles,
    // strips and fans become triangles.
    let s = real(&dir, "MeshPrimitiveModes/glTF/MeshPrimitiveModes.gltf");
    let json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("real/MeshPrimitiveModes/glTF/MeshPrimitiveModes.gltf"))
            .expect("read"),
    )
    .expect("json");
    let modes: Vec<u64> = json["meshes"]
        .as_array()
        .expect("meshes")
        .iter()
        .flat_map(|m| m["primitives"].as_array().cloned().unwrap_or_default())
        .map(|p| p["mode"].as_u64().unwrap_or(4))
        .collect();
    let triangle_prims = modes.iter().filter(|&&m| m >= 4).count();
    assert!(modes.iter().any(|&m| m < 4), "the asset has non-triangle modes");
    assert_eq!(s.meshes.len(), triangle_prims, "modes {modes:?}");
    assert!(s.meshes.iter().all(|m| !m.indices.is_empty()));

    // SimpleSparseAccessor: sparse values displace vertices 8, 10 and 12.
    let s = real(&dir, "SimpleSparseAccessor/glTF/SimpleSparseAccessor.gltf");
    let p = &s.meshes[0].positions;
    assert_eq!(p.len(), 14);
    assert_eq!(p[8], Vec3::new(1.0, 2.0, 0.0));
    assert_eq!(p[10], Vec3::new(3.0, 3.0, 0.0));
    assert_eq!(p[12], Vec3::new(5.0, 4.0, 0.0));
    assert_eq!(p[9], Vec3::new(2.0, 1.0, 0.0), "not sparse-replaced");
    let e = real(&dir, "SimpleSparseAccessor/glTF-Embedded/SimpleSparseAccessor.gltf");
    assert_eq!(e.meshes[0].positions, s.meshes[0].positions);

    // SimpleInstancing: many instances of few meshes, mesh data not duplicated.
    for f in [
        "SimpleInstancing/glTF/SimpleInstancing.gltf",
        "SimpleInstancing/glTF-Binary/SimpleInstancing.glb",
    ] {
        let s = real(&dir, f);
        assert!(s.instances.len() >= 100, "{f}: {} instances", s.instances.len());
        assert!(s.meshes.len() <= 2, "{f}: {} meshes", s.meshes.len());
        assert_eq!(s.triangle_count(), s.instances.len() * s.meshes[0].indices.len());
    }

    // TriangleWithoutIndices.
    for f in [
        "TriangleWithoutIndices/glTF/TriangleWithoutIndices.gltf",
        "TriangleWithoutIndices/glTF-Embedded/TriangleWithoutIndices.gltf",
    ] {
        let s = real(&dir, f);
        assert_eq!(s.meshes.len(), 1);
        assert_eq!(s.meshes[0].indices, vec![[0, 1, 2]]);
        assert_eq!(s.cameras[0].name, "default");
    }

    // Cameras: one perspective and one orthographic.
    let s = real(&dir, "Cameras/glTF/Cameras.gltf");
    assert_eq!(s.cameras.len(), 2);
    assert!(matches!(s.cameras[0].projection, crate::scene::Projection::Perspective { .. }));
    assert!(matches!(s.cameras[1].projection, crate::scene::Projection::Orthographic { .. }));
    // A thin lens fits the perspective camera and is refused on the orthographic one (naming
    // it), not dropped.
    let lens = crate::settings::Lens { aperture_radius: 0.05, focus_distance: 3.0 };
    let at = |camera: &str, lens| crate::settings::RenderSettings {
        camera: Some(camera.to_string()),
        lens,
        ..Default::default()
    };
    let (persp, ortho) = (s.cameras[0].name.clone(), s.cameras[1].name.clone());
    assert_eq!(s.check_lens(&at(&persp, lens)), Ok(()));
    assert_eq!(s.check_lens(&at(&ortho, crate::settings::Lens::default())), Ok(()));
    let e = s.check_lens(&at(&ortho, lens)).unwrap_err();
    assert!(e.contains("orthographic") && e.contains(&format!("'{ortho}'")), "{e}");

    // Emissive strength, texture transforms, vertex colours, textures.
    let s = real(&dir, "EmissiveStrengthTest/glTF-Binary/EmissiveStrengthTest.glb");
    assert!(s.materials.iter().any(|m| m.emissive.max_element() > 1.0));
    let s = real(&dir, "TextureTransformTest/glTF/TextureTransformTest.gltf");
    assert!(s
        .materials
        .iter()
        .any(|m| m.base_color_texture.is_some_and(|t| t.transform.is_some())));
    let s = real(&dir, "VertexColorTest/glTF-Binary/VertexColorTest.glb");
    assert!(s.meshes.iter().any(|m| m.colors.is_some()));
    let s = real(&dir, "DamagedHelmet/glTF-Binary/DamagedHelmet.glb");
    assert!(
        s.textures.len() >= 4
            && s.textures.iter().all(|t| t.texels.len() == (t.width * t.height) as usize)
    );
    assert!(s.meshes[0].normals.is_some() && s.meshes[0].uvs[0].is_some());
    assert!(s.materials[0].normal_texture.is_some() && s.materials[0].emissive_texture.is_some());
}

/// A resolver that records every path asked for and checks it stays inside the folder.
struct Recorder {
    inner: DirResolver,
    asked: RefCell<Vec<String>>,
}

impl Resolver for Recorder {
    fn read(&self, uri: &str) -> Result<Vec<u8>, String> {
        self.asked.borrow_mut().push(uri.to_string());
        self.inner.read(uri)
    }
}

/// Files of the suite that the validator reports no error for but that we refuse on purpose.
const VALID_BUT_REFUSED: &[(&str, &str)] = &[
    (
        "base/data/asset/min_version_valid.gltf",
        "minVersion 2.1: the asset needs glTF 2.1 features, which a 2.0 loader must not guess at",
    ),
    (
        "base/data/root/named_objects.gltf",
        "a .gltf whose buffer 0 has no uri: the mesh data is simply not in the file",
    ),
    (
        "base/data/root/unused_objects.gltf",
        "a .gltf whose buffer 0 has no uri: the mesh data is simply not in the file",
    ),
];

#[test]
fn validator_suite_never_panics_and_valid_files_load() {
    let dir = assets_dir();
    let suite = dir.join("invalid/validator-tests/test");
    let files = files_with_ext(&suite, true);
    assert!(files.len() >= 300, "expected the validator suite, found {} files", files.len());

    let mut panicked = Vec::new();
    let mut valid_failed = Vec::new();
    let (mut valid_ok, mut invalid_refused, mut invalid_accepted, mut valid_total) = (0, 0, 0, 0);
    let mut invalid_renderable = 0;
    let mut escapes = Vec::new();
    let mut accepted_names = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&suite).unwrap_or(f).to_string_lossy().replace('\\', "/");
        let report_path = PathBuf::from(format!("{}.report.json", f.display()));
        let report: serde_json::Value = std::fs::read(&report_path)
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_else(|| panic!("{rel}: no readable report"));
        let num_errors =
            report["issues"]["numErrors"].as_u64().unwrap_or_else(|| panic!("{rel}: no numErrors"));

        let outcome = catch_unwind(AssertUnwindSafe(|| load_path(f)));
        let result = match outcome {
            Ok(r) => r,
            Err(_) => {
                panicked.push(rel.clone());
                continue;
            }
        };
        // Same load through a recording resolver: every file asked for must lie in the folder.
        let folder = f.parent().expect("parent").to_path_buf();
        let recorder =
            Recorder { inner: DirResolver::new(&folder), asked: RefCell::new(Vec::new()) };
        let bytes = std::fs::read(f).expect("read");
        let again = catch_unwind(AssertUnwindSafe(|| load_slice(&bytes, &recorder)));
        if again.is_err() {
            panicked.push(format!("{rel} (load_slice)"));
            continue;
        }
        let base = folder.canonicalize().expect("canonical folder");
        for asked in recorder.asked.borrow().iter() {
            let lexical_ok =
                !asked.starts_with('/') && !asked.split('/').any(|p| p == ".." || p.is_empty());
            let inside = base.join(asked).canonicalize().map_or(true, |p| p.starts_with(&base));
            if !lexical_ok || !inside {
                escapes.push(format!("{rel}: asked for {asked}"));
            }
        }

        if let Err(e) = &result {
            assert!(!e.0.trim().is_empty(), "{rel}: empty error message");
        }
        if num_errors == 0 {
            valid_total += 1;
            match (&result, VALID_BUT_REFUSED.iter().find(|(name, _)| *name == rel)) {
                (Ok(_), None) => valid_ok += 1,
                (Err(_), Some(_)) => {}
                (Ok(_), Some((_, why))) => {
                    valid_failed.push(format!("{rel}: listed as refused ({why}) but loads"))
                }
                (Err(e), None) => valid_failed.push(format!("{rel}: {e}")),
            }
        } else {
            match &result {
                Err(_) => invalid_refused += 1,
                Ok(scene) => {
                    invalid_accepted += 1;
                    if check_renderable(scene).is_ok() {
                        invalid_renderable += 1;
                        accepted_names.push(format!("{rel} (renderable)"));
                    } else {
                        accepted_names.push(rel.clone());
                    }
                }
            }
        }
    }
    println!(
        "validator suite: {} files; {valid_total} valid of which {valid_ok} load and {} are refused on purpose; \
         {} invalid of which {invalid_refused} are refused and {invalid_accepted} accepted \
         ({invalid_renderable} of those with triangles to render; the others fail check_renderable)",
        files.len(),
        VALID_BUT_REFUSED.len(),
        invalid_refused + invalid_accepted
    );
    if std::env::var_os("GLTF_SUITE_VERBOSE").is_some() {
        println!("accepted invalid files:\n  {}", accepted_names.join("\n  "));
    }
    assert!(panicked.is_empty(), "panicked on:\n{}", panicked.join("\n"));
    assert!(escapes.is_empty(), "URIs escaped the folder:\n{}", escapes.join("\n"));
    assert!(valid_failed.is_empty(), "valid files that failed:\n{}", valid_failed.join("\n"));
    assert!(invalid_refused > 0);
}
