//! Scene bundles: what a user uploads and a worker downloads, as one byte string.
//!
//! A bundle is a `.glb`, a `.gltf` whose buffers and images are `data:` URIs, or a `.zip` of a
//! folder holding one `.gltf`/`.glb` and the files it names (and, optionally, the environment
//! map the settings name). The format is recognised from the bytes, never from a name. Files are
//! resolved only inside the archive, relative to the scene file's folder; an entry whose name
//! would escape the archive (`..`, absolute paths) is refused, and the archive's size is bounded
//! before anything is inflated beyond it.

use std::{
    collections::HashMap,
    io::{Cursor, Read, Write},
};

use crate::{
    budget::{over_budget, Line, SceneBudget},
    envmap::EnvMap,
    gltf::{check_renderable, load_slice_spread, NoFiles, Resolver, SceneError},
    scene::Scene,
    spread::{InOrder, Spread},
};

/// The formats a bundle can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Binary glTF.
    Glb,
    /// glTF JSON with `data:` URIs only.
    Gltf,
    /// A zip archive of a folder.
    Zip,
}

impl Format {
    /// Recognises the format from the first bytes, or says what the bytes look like instead.
    pub fn detect(bytes: &[u8]) -> Result<Format, SceneError> {
        if bytes.starts_with(b"glTF") {
            Ok(Format::Glb)
        } else if bytes.starts_with(b"PK\x03\x04") || bytes.starts_with(b"PK\x05\x06") {
            Ok(Format::Zip)
        } else if bytes.iter().find(|b| !b.is_ascii_whitespace()).is_some_and(|&b| b == b'{')
            || bytes.starts_with(&[0xEF, 0xBB, 0xBF])
        {
            Ok(Format::Gltf)
        } else if bytes.is_empty() {
            Err(SceneError("the upload is empty".into()))
        } else {
            Err(SceneError(
                "not a scene: expected a .glb (magic \"glTF\"), a .gltf (a JSON object) or a .zip"
                    .into(),
            ))
        }
    }

    /// The name used in the API (`glb`, `gltf`, `zip`).
    pub fn name(self) -> &'static str {
        match self {
            Format::Glb => "glb",
            Format::Gltf => "gltf",
            Format::Zip => "zip",
        }
    }
}

/// An opened bundle: the scene file's bytes and, for an archive, the other files by path.
#[derive(Clone, Debug)]
pub struct Bundle {
    /// The format of the original bytes.
    pub format: Format,
    /// Path of the scene file inside the archive (empty for a bare `.glb`/`.gltf`).
    pub main_path: String,
    main: Vec<u8>,
    /// Folder of the scene file inside the archive, with a trailing `/` (or empty).
    dir: String,
    files: HashMap<String, Vec<u8>>,
    /// What loading the scene may cost.
    budget: SceneBudget,
}

impl Bundle {
    /// Opens the bytes of an upload within `budget`: an archive is inflated entry by entry,
    /// never past the budget's bytes, and the scene it holds is loaded within its texels and
    /// triangles ([`Bundle::load_scene`]).
    pub fn open(bytes: &[u8], budget: &SceneBudget) -> Result<Bundle, SceneError> {
        let budget = *budget;
        let format = Format::detect(bytes)?;
        if format != Format::Zip {
            return Ok(Bundle {
                format,
                main_path: String::new(),
                main: bytes.to_vec(),
                dir: String::new(),
                files: HashMap::new(),
                budget,
            });
        }
        let zip_err = |e: zip::result::ZipError| SceneError(format!("zip: {e}"));
        let mut archive = zip::ZipArchive::new(Cursor::new(bytes)).map_err(zip_err)?;
        if archive.len() as u64 > budget.entries {
            return Err(over_budget(
                Line::Entries,
                archive.len() as u64,
                budget.entries,
                "the zip's directory",
            ));
        }
        let mut files = HashMap::new();
        let mut total = 0u64;
        for i in 0..archive.len() {
            let mut entry = archive.by_index(i).map_err(zip_err)?;
            if entry.is_dir() {
                continue;
            }
            let raw = entry.name().to_string();
            let Some(path) = entry.enclosed_name() else {
                return Err(SceneError(format!("zip: entry '{raw}' points outside the archive")));
            };
            let name = path
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join("/");
            if name.starts_with("__MACOSX/") {
                continue;
            }
            // The size the entry declares is checked first; the bytes are then read, never more
            // than the budget has left, since a declared size can lie.
            let left = budget.inflated_bytes.saturating_sub(total);
            if entry.size() > left {
                let needed = total.saturating_add(entry.size());
                return Err(over_budget(
                    Line::InflatedBytes,
                    needed,
                    budget.inflated_bytes,
                    &format!("zip entry '{name}' declares {} bytes", entry.size()),
                ));
            }
            let mut data = Vec::with_capacity(entry.size() as usize);
            (&mut entry)
                .take(left + 1)
                .read_to_end(&mut data)
                .map_err(|e| SceneError(format!("zip: entry '{name}': {e}")))?;
            total += data.len() as u64;
            if total > budget.inflated_bytes {
                return Err(over_budget(
                    Line::InflatedBytes,
                    total,
                    budget.inflated_bytes,
                    &format!("zip entry '{name}'"),
                ));
            }
            files.insert(name, data);
        }
        let mut scenes: Vec<&String> = files
            .keys()
            .filter(|k| {
                let lower = k.to_ascii_lowercase();
                lower.ends_with(".gltf") || lower.ends_with(".glb")
            })
            .collect();
        scenes.sort_by_key(|k| (k.matches('/').count(), k.to_string()));
        let main_path = match scenes.as_slice() {
            [] => return Err(SceneError("zip: holds no .gltf or .glb file".into())),
            [one] => (*one).clone(),
            [a, b, ..] if a.matches('/').count() < b.matches('/').count() => (*a).clone(),
            many => {
                let names: Vec<&str> = many.iter().map(|s| s.as_str()).collect();
                return Err(SceneError(format!(
                    "zip: holds several scene files at the same depth ({}); upload one scene per archive",
                    names.join(", ")
                )));
            }
        };
        let main = files.remove(&main_path).unwrap_or_default();
        let dir = match main_path.rfind('/') {
            Some(i) => main_path[..=i].to_string(),
            None => String::new(),
        };
        Ok(Bundle { format, main_path, main, dir, files, budget })
    }

    /// Loads the scene and checks that it has something to render.
    pub fn load_scene(&self) -> Result<Scene, SceneError> {
        self.load_scene_spread(&InOrder)
    }

    /// [`Bundle::load_scene`], decoding the images on the threads `spread` lends.
    pub fn load_scene_spread(&self, spread: &dyn Spread) -> Result<Scene, SceneError> {
        let scene = if self.format == Format::Zip {
            load_slice_spread(&self.main, self, &self.budget, spread)
        } else {
            load_slice_spread(&self.main, &NoFiles, &self.budget, spread)
        }
        .map_err(|e| match self.main_path.as_str() {
            "" => e,
            path => SceneError(format!("{path}: {e}")),
        })?;
        check_renderable(&scene)?;
        Ok(scene)
    }

    /// Every file of the bundle as `(path, bytes)`, the scene file first (named `main_path`, or
    /// `scene.glb`/`scene.gltf` for a bare file): what [`Bundle::pack`] takes back.
    pub fn into_files(self) -> Vec<(String, Vec<u8>)> {
        let main_path = match (self.main_path.is_empty(), self.format) {
            (false, _) => self.main_path,
            (true, Format::Glb) => "scene.glb".to_string(),
            (true, _) => "scene.gltf".to_string(),
        };
        let mut rest: Vec<(String, Vec<u8>)> = self.files.into_iter().collect();
        rest.sort_by(|a, b| a.0.cmp(&b.0));
        std::iter::once((main_path, self.main)).chain(rest).collect()
    }

    /// Loads the environment map at `path` (relative to the scene file's folder).
    pub fn load_envmap(&self, path: &str) -> Result<EnvMap, String> {
        let bytes = self.read(path)?;
        EnvMap::from_bytes(path, &bytes).map_err(|e| e.to_string())
    }

    /// Builds a zip archive (stored, uncompressed) from `(path, bytes)` pairs.
    pub fn pack(files: &[(String, Vec<u8>)]) -> std::io::Result<Vec<u8>> {
        let mut writer = zip::ZipWriter::new(Cursor::new(Vec::new()));
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored)
            .large_file(files.iter().any(|(_, b)| b.len() as u64 >= u32::MAX as u64));
        for (name, bytes) in files {
            writer.start_file(name.as_str(), options).map_err(std::io::Error::other)?;
            writer.write_all(bytes)?;
        }
        Ok(writer.finish().map_err(std::io::Error::other)?.into_inner())
    }
}

impl Resolver for Bundle {
    fn read(&self, uri: &str) -> Result<Vec<u8>, String> {
        let mut parts: Vec<&str> = Vec::new();
        for seg in self.dir.split('/').chain(uri.split('/')) {
            match seg {
                "" | "." => {}
                ".." => {
                    if parts.pop().is_none() {
                        return Err(format!("'{uri}' points outside the bundle"));
                    }
                }
                s => parts.push(s),
            }
        }
        let key = parts.join("/");
        self.files
            .get(&key)
            .cloned()
            .ok_or_else(|| format!("'{uri}' is not in the uploaded bundle"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detects_formats_from_bytes() {
        assert_eq!(Format::detect(b"glTF\x02\0\0\0").unwrap(), Format::Glb);
        assert_eq!(Format::detect(b"  {\"asset\":{}}").unwrap(), Format::Gltf);
        assert_eq!(Format::detect(b"PK\x03\x04rest").unwrap(), Format::Zip);
        assert!(Format::detect(b"").unwrap_err().0.contains("empty"));
        assert!(Format::detect(b"GIF89a").unwrap_err().0.contains("not a scene"));
    }

    #[test]
    fn zip_resolves_inside_the_archive_only() {
        let packed = Bundle::pack(&[
            ("scene/a.gltf".into(), b"{}".to_vec()),
            ("scene/buf/b.bin".into(), vec![1, 2, 3]),
            ("top.bin".into(), vec![9]),
        ])
        .unwrap();
        let bundle = Bundle::open(&packed, &SceneBudget::default()).unwrap();
        assert_eq!(bundle.main_path, "scene/a.gltf");
        assert_eq!(bundle.read("buf/b.bin").unwrap(), vec![1, 2, 3]);
        assert_eq!(bundle.read("../top.bin").unwrap(), vec![9]);
        assert!(bundle.read("../../etc/passwd").unwrap_err().contains("outside"));
        assert!(bundle.read("missing.bin").unwrap_err().contains("not in the uploaded bundle"));
    }

    /// A small zip that inflates to far more than the budget is refused from the size its entry
    /// declares, before anything is inflated.
    #[test]
    fn a_zip_bomb_is_refused_before_inflating() {
        use std::io::Write as _;
        let mut writer = zip::ZipWriter::new(Cursor::new(Vec::new()));
        let deflated = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated);
        writer.start_file("scene.gltf", deflated).unwrap();
        let zeros = vec![b' '; 1 << 20];
        for _ in 0..64 {
            writer.write_all(&zeros).unwrap();
        }
        let bomb = writer.finish().unwrap().into_inner();
        assert!(bomb.len() < 200_000, "64 MiB of spaces deflate to {} bytes", bomb.len());
        let budget = SceneBudget { inflated_bytes: 1 << 20, ..SceneBudget::default() };
        let e = Bundle::open(&bomb, &budget).unwrap_err().0;
        assert!(e.contains("67.1 M bytes unpacked") && e.contains("declares 67108864"), "{e}");
    }

    #[test]
    fn zip_limits_and_ambiguity_are_refused() {
        let two =
            Bundle::pack(&[("a.gltf".into(), b"{}".to_vec()), ("b.glb".into(), vec![])]).unwrap();
        assert!(Bundle::open(&two, &SceneBudget::default()).unwrap_err().0.contains("several"));
        let big = Bundle::pack(&[("a.gltf".into(), vec![b' '; 1000])]).unwrap();
        let budget = SceneBudget { inflated_bytes: 100, ..SceneBudget::default() };
        let e = Bundle::open(&big, &budget).unwrap_err().0;
        assert!(e.contains("1000 bytes unpacked") && e.contains("--max-scene-mib"), "{e}");
        let many: Vec<(String, Vec<u8>)> =
            (0..11).map(|i| (format!("{i}.gltf"), b"{}".to_vec())).collect();
        let budget = SceneBudget { entries: 10, ..SceneBudget::default() };
        let e = Bundle::open(&Bundle::pack(&many).unwrap(), &budget).unwrap_err().0;
        assert!(e.contains("11 files"), "{e}");
        let none = Bundle::pack(&[("readme.txt".into(), vec![])]).unwrap();
        assert!(Bundle::open(&none, &SceneBudget::default()).unwrap_err().0.contains("no .gltf"));
        let truncated = &two[..two.len() / 2];
        assert!(Bundle::open(truncated, &SceneBudget::default())
            .unwrap_err()
            .0
            .starts_with("zip:"));
    }
}
