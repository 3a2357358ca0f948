//! `KHR_draco_mesh_compression`: a primitive that carries the extension has its indices and the
//! attributes the extension lists decoded from the Draco stream in the buffer view it names
//! (the `draco-core` crate, a Rust decoder of the Draco bitstream). The decoded values are laid
//! out as the primitive's accessors describe them (their component type and count, tightly
//! packed), so that the accessor reader takes them in place of a buffer view and everything
//! after it (normalisation, counts, skins) is unchanged. The accessors' sizes are charged to the
//! unpacked-bytes budget from the JSON before anything is decoded, and the decoder runs under
//! limits of that many points, faces and bytes.

use ::gltf::json;
use json::accessor::ComponentType;
use json::mesh::{Mode, Semantic};
use json::validation::Checked;
use serde_json::Value;

use super::accessor::component_size;
use super::{fail, Context, Loader, SceneError};
use crate::budget;

/// The extension's name.
pub(crate) const EXTENSION: &str = "KHR_draco_mesh_compression";

impl Loader<'_> {
    /// Decodes the Draco stream of primitive `prim` of mesh `mesh` into `self.draco` (the bytes
    /// of its indices accessor and of each attribute accessor the extension lists), once; a
    /// primitive without the extension is left alone.
    pub(crate) fn decode_draco(&self, mesh: usize, prim: usize) -> Result<(), SceneError> {
        let p = &self.root.meshes[mesh].primitives[prim];
        let Some(ext) = p.extensions.as_ref().and_then(|e| e.others.get(EXTENSION)) else {
            return Ok(());
        };
        self.decode_draco_ext(p, ext).context(|| EXTENSION.to_string())
    }

    fn decode_draco_ext(&self, p: &json::mesh::Primitive, ext: &Value) -> Result<(), SceneError> {
        if !matches!(p.mode, Checked::Valid(Mode::Triangles)) {
            return fail("only TRIANGLES primitives can be Draco-compressed");
        }
        let Some(view) = ext.get("bufferView").and_then(Value::as_u64) else {
            return fail("bufferView must be an index");
        };
        let Some(listed) = ext.get("attributes").and_then(Value::as_object) else {
            return fail("attributes must be an object of attribute ids");
        };
        // (accessor, Draco attribute id) of each listed attribute, then the indices.
        let mut targets: Vec<(usize, Option<u32>)> = Vec::new();
        for (name, id) in listed {
            let Some(id) = id.as_u64().and_then(|i| u32::try_from(i).ok()) else {
                return fail(format!("attribute {name}: {id} is not an attribute id"));
            };
            let semantic: Checked<Semantic> =
                serde_json::from_value(Value::String(name.clone())).unwrap_or(Checked::Invalid);
            let Some(acc) = p.attributes.get(&semantic) else {
                return fail(format!("attribute {name} is not an attribute of the primitive"));
            };
            targets.push((acc.value(), Some(id)));
        }
        if let Some(indices) = p.indices {
            targets.push((indices.value(), None));
        }
        if targets.iter().all(|&(acc, _)| self.draco.borrow().contains_key(&acc)) {
            return Ok(());
        }
        // The accessors' sizes, charged before anything is decoded; the decoder may produce no
        // more points, faces or bytes than they describe.
        let mut bytes = 0u64;
        let mut points = 0u64;
        for &(acc, id) in &targets {
            let info = self.accessor_info(acc)?;
            bytes +=
                info.count as u64 * (info.components() * component_size(info.component)) as u64;
            if id.is_some() {
                points = points.max(info.count as u64);
            }
        }
        let faces = match p.indices {
            Some(i) => self.accessor_info(i.value())?.count as u64 / 3,
            None => points / 3,
        };
        self.charge_scene(budget::Line::InflatedBytes, bytes, || {
            format!("Draco stream of {points} points and {faces} triangles")
        })?;
        let (stream, _) = self.view(view as usize)?;
        let limits = draco_core::DecodeLimits::default()
            .with_max_points(points)
            .with_max_faces(faces)
            .with_max_decoded_bytes(bytes.max(1));
        let mut buffer = draco_core::DecoderBuffer::new(stream).with_limits(limits);
        let mut mesh = draco_core::Mesh::new();
        draco_core::MeshDecoder::new().decode(&mut buffer, &mut mesh).map_err(|e| {
            SceneError(format!("cannot decode the stream of buffer view {view}: {e}"))
        })?;
        let num_points = mesh.num_points();
        for &(acc, id) in &targets {
            let info = self.accessor_info(acc)?;
            let values: Vec<f64> = match id {
                Some(id) => {
                    let Some(attribute) = mesh.attribute_by_unique_id(id) else {
                        return fail(format!("the stream has no attribute {id}"));
                    };
                    if num_points != info.count {
                        return fail(format!(
                            "the stream decodes to {num_points} points, but accessor {acc} has {}",
                            info.count
                        ));
                    }
                    if attribute.num_components() as usize != info.components() {
                        return fail(format!(
                            "attribute {id} has {} components, accessor {acc} is {}",
                            attribute.num_components(),
                            info.describe()
                        ));
                    }
                    attribute
                        .read_f32s(num_points, info.components())
                        .into_iter()
                        .map(f64::from)
                        .collect()
                }
                None => {
                    if mesh.num_faces() * 3 != info.count {
                        return fail(format!(
                            "the stream decodes to {} triangles, but indices accessor {acc} has {} indices",
                            mesh.num_faces(),
                            info.count
                        ));
                    }
                    (0..mesh.num_faces())
                        .flat_map(|f| mesh.face(draco_core::FaceIndex(f as u32)))
                        .map(|i| f64::from(i.0))
                        .collect()
                }
            };
            let packed = pack(&values, info.component).ok_or_else(|| {
                SceneError(format!("accessor {acc}: a value does not fit {}", info.describe()))
            })?;
            self.draco.borrow_mut().entry(acc).or_insert_with(|| packed.into());
        }
        Ok(())
    }
}

/// `values` as little-endian components of type `c`; `None` if one does not fit.
fn pack(values: &[f64], c: ComponentType) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(values.len() * component_size(c));
    for &v in values {
        let fits = |lo: f64, hi: f64| v.fract() == 0.0 && (lo..=hi).contains(&v);
        match c {
            ComponentType::F32 => out.extend((v as f32).to_le_bytes()),
            ComponentType::I8 if fits(-128.0, 127.0) => out.push(v as i8 as u8),
            ComponentType::U8 if fits(0.0, 255.0) => out.push(v as u8),
            ComponentType::I16 if fits(-32768.0, 32767.0) => out.extend((v as i16).to_le_bytes()),
            ComponentType::U16 if fits(0.0, 65535.0) => out.extend((v as u16).to_le_bytes()),
            ComponentType::U32 if fits(0.0, u32::MAX as f64) => {
                out.extend((v as u32).to_le_bytes())
            }
            _ => return None,
        }
    }
    Some(out)
}
