//! Mesh primitives into [`Mesh`]es: triangle lists, strips and fans (other modes are skipped),
//! indexed or not, with POSITION, NORMAL, TANGENT, TEXCOORD_0/1 and COLOR_0 checked and
//! converted; each (mesh, primitive) pair is built once however many nodes use it.

use ::gltf::json;
use glam::{Vec2, Vec3, Vec4};
use json::accessor::Type;
use json::mesh::{Mode, Semantic};
use json::validation::Checked;

use super::tangents::clean_tangent;
use super::{fail, Context, Loader, SceneError};
use crate::scene::Mesh;

impl Loader<'_> {
    /// The scene mesh of primitive `prim` of glTF mesh `mesh`, built on first use; `None` when
    /// the primitive has no triangles to render.
    pub(crate) fn mesh_index(
        &mut self,
        mesh: usize,
        prim: usize,
    ) -> Result<Option<usize>, SceneError> {
        if let Some(&known) = self.mesh_map.get(&(mesh, prim)) {
            return Ok(known);
        }
        let built =
            self.build_primitive(mesh, prim).context(|| format!("mesh {mesh} primitive {prim}"))?;
        let mappings = self
            .variant_mappings(mesh, prim)
            .context(|| format!("mesh {mesh} primitive {prim}: KHR_materials_variants"))?;
        let index = built.map(|(m, material)| {
            self.meshes.push(m);
            self.mesh_materials.push(material);
            self.mesh_variant_materials.push(mappings);
            self.meshes.len() - 1
        });
        self.mesh_map.insert((mesh, prim), index);
        Ok(index)
    }

    /// The primitive's `KHR_materials_variants` mappings as (variant, glTF material) pairs; a
    /// variant mapped twice takes its first mapping.
    pub(crate) fn variant_mappings(
        &self,
        mesh: usize,
        prim: usize,
    ) -> Result<Vec<(usize, usize)>, SceneError> {
        let prim = &self.root.meshes[mesh].primitives[prim];
        let ext = prim.extensions.as_ref().and_then(|e| e.others.get("KHR_materials_variants"));
        let Some(ext) = ext else { return Ok(Vec::new()) };
        let Some(mappings) = ext.get("mappings").and_then(|m| m.as_array()) else {
            return fail("mappings must be an array");
        };
        let index = |v: &serde_json::Value, what: &str, len: usize| match v.as_u64() {
            Some(i) if (i as usize) < len => Ok(i as usize),
            _ => fail(format!("{what} {v} does not exist (the file has {len})")),
        };
        let mut pairs: Vec<(usize, usize)> = Vec::new();
        for (k, mapping) in mappings.iter().enumerate() {
            let material = mapping.get("material").unwrap_or(&serde_json::Value::Null);
            let material = index(material, "material", self.root.materials.len())
                .context(|| format!("mappings[{k}]"))?;
            let Some(variants) = mapping.get("variants").and_then(|v| v.as_array()) else {
                return fail(format!("mappings[{k}]: variants must be an array of indices"));
            };
            for v in variants {
                let v = index(v, "variant", self.variants.len())
                    .context(|| format!("mappings[{k}]"))?;
                if !pairs.iter().any(|(known, _)| *known == v) {
                    pairs.push((v, material));
                }
            }
        }
        Ok(pairs)
    }

    pub(crate) fn build_primitive(
        &self,
        mesh_index: usize,
        prim_index: usize,
    ) -> Result<Option<(Mesh, Option<usize>)>, SceneError> {
        let mesh = &self.root.meshes[mesh_index];
        let prim = &mesh.primitives[prim_index];
        let mesh_name = mesh.name.clone().unwrap_or_else(|| format!("mesh {mesh_index}"));
        let mode = match prim.mode {
            Checked::Valid(m) => m,
            Checked::Invalid => return fail("invalid mode"),
        };
        if matches!(mode, Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip) {
            tracing::warn!("mesh {mesh_index} ({mesh_name}) primitive {prim_index}: mode {mode:?} has no triangles; skipped");
            return Ok(None);
        }
        // A Draco-compressed primitive's accessors are read from its decoded stream.
        self.decode_draco(mesh_index, prim_index)?;
        let attribute = |s: Semantic| prim.attributes.get(&Checked::Valid(s)).map(|i| i.value());
        let Some(pos_acc) = attribute(Semantic::Positions) else {
            tracing::warn!(
                "mesh {mesh_index} ({mesh_name}) primitive {prim_index}: no POSITION; skipped"
            );
            return Ok(None);
        };
        let material = match prim.material {
            Some(m) if m.value() >= self.root.materials.len() => {
                return fail(format!(
                    "material {} does not exist (the file has {} materials)",
                    m.value(),
                    self.root.materials.len()
                ))
            }
            m => m.map(|m| m.value()),
        };

        let positions: Vec<Vec3> = self.read_vectors(pos_acc, &[Type::Vec3], "POSITION")?;
        if let Some(bad) = positions.iter().position(|p| !p.is_finite()) {
            return fail(format!("accessor {pos_acc}: non-finite position at element {bad}"));
        }
        let vertex_count = positions.len();
        let same_count = |acc: usize, what: &str, len: usize| -> Result<(), SceneError> {
            if len != vertex_count {
                return fail(format!(
                    "{what} accessor {acc} has {len} elements but POSITION accessor {pos_acc} has {vertex_count}"
                ));
            }
            Ok(())
        };

        // Vertex order, then triangles.
        let order: Vec<u32> = match prim.indices {
            Some(acc) => {
                let acc = acc.value();
                let indices = self.read_indices(acc)?;
                if let Some(&bad) = indices.iter().find(|&&i| i as usize >= vertex_count) {
                    return fail(format!(
                        "accessor {acc}: index {bad} out of range for {vertex_count} vertices"
                    ));
                }
                indices
            }
            None => {
                if vertex_count > u32::MAX as usize {
                    return fail(format!(
                        "{vertex_count} vertices are too many for 32-bit indices"
                    ));
                }
                (0..vertex_count as u32).collect()
            }
        };
        let indices = triangulate(mode, &order);
        let used = match mode {
            Mode::Triangles => indices.len() * 3,
            _ if order.len() >= 3 => order.len(),
            _ => 0,
        };
        if used != order.len() {
            tracing::warn!(
                "mesh {mesh_index} ({mesh_name}) primitive {prim_index}: {} trailing vertices do not form a triangle; ignored",
                order.len() - used
            );
        }

        let normals = match attribute(Semantic::Normals) {
            Some(acc) => {
                let n: Vec<Vec3> = self.read_vectors(acc, &[Type::Vec3], "NORMAL")?;
                same_count(acc, "NORMAL", n.len())?;
                Some(repair_normals(n, &positions, &indices, || {
                    format!("mesh {mesh_index} ({mesh_name}) primitive {prim_index}")
                }))
            }
            None => None,
        };
        let tangents = match attribute(Semantic::Tangents) {
            Some(acc) => {
                let t: Vec<Vec4> = self.read_vectors(acc, &[Type::Vec4], "TANGENT")?;
                same_count(acc, "TANGENT", t.len())?;
                let clean: Option<Vec<Vec4>> = t.into_iter().map(clean_tangent).collect();
                clean.or_else(|| {
                    tracing::warn!(
                        "mesh {mesh_index} ({mesh_name}) primitive {prim_index}: TANGENT accessor {acc} has zero or non-finite tangents; tangents dropped (generated where a material needs them)"
                    );
                    None
                })
            }
            None => None,
        };
        let mut uvs: [Option<Vec<Vec2>>; 2] = [None, None];
        for (set, slot) in uvs.iter_mut().enumerate() {
            if let Some(acc) = attribute(Semantic::TexCoords(set as u32)) {
                let what = format!("TEXCOORD_{set}");
                let uv: Vec<Vec2> = self.read_vectors(acc, &[Type::Vec2], &what)?;
                same_count(acc, &what, uv.len())?;
                if let Some(bad) = uv.iter().position(|v| !v.is_finite()) {
                    return fail(format!(
                        "accessor {acc}: non-finite texture coordinate at element {bad}"
                    ));
                }
                *slot = Some(uv);
            }
        }
        let colors = match attribute(Semantic::Colors(0)) {
            Some(acc) => {
                let (info, values) = self.read_f32(acc)?;
                let rgba: Vec<Vec4> = match info.ty {
                    Type::Vec3 => {
                        values.chunks_exact(3).map(|c| Vec4::new(c[0], c[1], c[2], 1.0)).collect()
                    }
                    Type::Vec4 => values.chunks_exact(4).map(Vec4::from_slice).collect(),
                    _ => {
                        return fail(format!(
                            "COLOR_0 accessor {acc} must be VEC3 or VEC4, not {}",
                            info.describe()
                        ))
                    }
                };
                same_count(acc, "COLOR_0", rgba.len())?;
                if let Some(bad) = rgba.iter().position(|c| !c.is_finite()) {
                    return fail(format!("accessor {acc}: non-finite colour at element {bad}"));
                }
                Some(rgba.into_iter().map(|c| c.clamp(Vec4::ZERO, Vec4::ONE)).collect())
            }
            None => None,
        };

        let mesh = Mesh {
            name: format!("{mesh_name}/{prim_index}"),
            positions,
            normals,
            tangents,
            uvs,
            colors,
            indices,
            material: 0,                   // set once the used materials are known
            variant_materials: Vec::new(), // likewise
            deform: None,                  // set for a deforming placement
        };
        Ok(Some((mesh, material)))
    }

    /// Reads an accessor of one of the `allowed` vector types into glam vectors.
    pub(crate) fn read_vectors<V: FromFloats>(
        &self,
        acc: usize,
        allowed: &[Type],
        what: &str,
    ) -> Result<Vec<V>, SceneError> {
        let (info, values) = self.read_f32(acc)?;
        if !allowed.contains(&info.ty) {
            return fail(format!(
                "{what} accessor {acc} must be {:?}, not {}",
                allowed,
                info.describe()
            ));
        }
        Ok(values.chunks_exact(info.components()).map(V::from_floats).collect())
    }
}

/// glam vectors built from a slice of floats of the right length.
pub(crate) trait FromFloats {
    fn from_floats(c: &[f32]) -> Self;
}
impl FromFloats for Vec2 {
    fn from_floats(c: &[f32]) -> Self {
        Vec2::from_slice(c)
    }
}
impl FromFloats for Vec3 {
    fn from_floats(c: &[f32]) -> Self {
        Vec3::from_slice(c)
    }
}
impl FromFloats for Vec4 {
    fn from_floats(c: &[f32]) -> Self {
        Vec4::from_slice(c)
    }
}

/// Triangles of a primitive from its vertex order (spec 3.7.2.1); trailing vertices that do not
/// make a triangle are dropped.
pub(crate) fn triangulate(mode: Mode, v: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::Triangles => v.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        Mode::TriangleStrip => {
            (0..v.len().saturating_sub(2))
                .map(|i| {
                    if i % 2 == 0 {
                        [v[i], v[i + 1], v[i + 2]]
                    } else {
                        [v[i], v[i + 2], v[i + 1]]
                    }
                })
                .collect()
        }
        Mode::TriangleFan => {
            (1..v.len().saturating_sub(1)).map(|i| [v[i], v[i + 1], v[0]]).collect()
        }
        _ => Vec::new(),
    }
}

/// Normalises normals; a zero or non-finite normal is replaced by the area-weighted normal of
/// the triangles around its vertex (or +z if it has none).
fn repair_normals(
    mut normals: Vec<Vec3>,
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    name: impl Fn() -> String,
) -> Vec<Vec3> {
    let mut bad = 0usize;
    for n in normals.iter_mut() {
        match n.try_normalize() {
            Some(u) => *n = u,
            None => {
                *n = Vec3::NAN;
                bad += 1;
            }
        }
    }
    if bad == 0 {
        return normals;
    }
    tracing::warn!("{}: {bad} zero or non-finite normals replaced by face normals", name());
    let mut sums = vec![Vec3::ZERO; normals.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let face = (b - a).cross(c - a);
        if face.is_finite() {
            for &i in t {
                sums[i as usize] += face;
            }
        }
    }
    for (n, s) in normals.iter_mut().zip(sums) {
        if n.is_nan() {
            *n = s.try_normalize().unwrap_or(Vec3::Z);
        }
    }
    normals
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_follow_the_spec() {
        assert_eq!(
            triangulate(Mode::TriangleStrip, &[0, 1, 2, 3, 4]),
            vec![[0, 1, 2], [1, 3, 2], [2, 3, 4]]
        );
        assert_eq!(triangulate(Mode::TriangleFan, &[0, 1, 2, 3]), vec![[1, 2, 0], [2, 3, 0]]);
        assert_eq!(triangulate(Mode::Triangles, &[0, 1, 2, 3]), vec![[0, 1, 2]]);
        assert!(triangulate(Mode::TriangleStrip, &[0, 1]).is_empty());
        assert!(triangulate(Mode::TriangleFan, &[]).is_empty());
    }

    #[test]
    fn bad_normals_are_repaired() {
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let n = repair_normals(
            vec![Vec3::ZERO, Vec3::new(0.0, 0.0, 2.0), Vec3::NAN],
            &p,
            &[[0, 1, 2]],
            String::new,
        );
        assert_eq!(n, vec![Vec3::Z, Vec3::Z, Vec3::Z]);
    }
}
