//! MikkTSpace tangents for the meshes whose material needs a tangent frame (a normal map, a
//! clear coat's normal map, anisotropy) and whose file gives none (glTF 2.0, 3.7.2.1: "when
//! tangents are not specified, client implementations SHOULD calculate tangents using default
//! MikkTSpace algorithms"): made from the normals and the texture coordinates the map reads, one
//! per face corner, each vertex split where its corners disagree. A mesh without normals or
//! without those coordinates is left as it is; the renderer then orients its maps by each
//! triangle's texture coordinates.

use std::collections::{HashMap, HashSet};

use bevy_mikktspace::{Geometry, TangentSpace};
use glam::{Vec2, Vec3, Vec4};

use super::{Loader, SceneError};
use crate::scene::{Material, Mesh};

/// The tangent of a corner that MikkTSpace cannot orient (a degenerate triangle with no
/// neighbour to take a frame from): the reference implementation's default, +x with the
/// bitangent along +y, in glTF's handedness.
const UNORIENTED: Vec4 = Vec4::new(1.0, 0.0, 0.0, 1.0);

impl Loader<'_> {
    /// Gives each placed mesh that has normals and no tangents, and whose material (or one of
    /// its `KHR_materials_variants` materials) needs a tangent frame, MikkTSpace tangents over
    /// the texture coordinates that frame is for. The work is linear in the mesh's triangles,
    /// which placing it charged to the scene's budget; the vertices it adds are at most three
    /// per triangle.
    pub(crate) fn generate_tangents(&mut self, materials: &[Material]) -> Result<(), SceneError> {
        let placed: HashSet<usize> = self.instances.iter().map(|i| i.mesh).collect();
        for index in 0..self.meshes.len() {
            let mesh = &self.meshes[index];
            if mesh.tangents.is_some() || !placed.contains(&index) {
                continue;
            }
            let uv_set = std::iter::once(mesh.material)
                .chain(mesh.variant_materials.iter().map(|&(_, m)| m))
                .find_map(|m| materials[m].tangent_uv_set());
            let Some(uv_set) = uv_set else { continue };
            let Some(uvs) = mesh.uvs.get(uv_set as usize).and_then(Option::as_ref) else {
                continue;
            };
            // A deforming mesh's tangents are made at rest, and posed like its normals.
            let (positions, normals) = match &mesh.deform {
                Some(d) => (&d.rest_positions, d.rest_normals.as_ref()),
                None => (&mesh.positions, mesh.normals.as_ref()),
            };
            let Some(normals) = normals else { continue };
            let split = mikktspace(positions, normals, uvs, &mesh.indices)
                .map_err(|e| SceneError(format!("mesh {}: {e}", mesh.name)))?;
            let before = mesh.positions.len();
            let mesh = &mut self.meshes[index];
            split.apply(mesh);
            tracing::debug!(
                "mesh {}: MikkTSpace tangents generated over TEXCOORD_{}; {} vertices split into {}",
                mesh.name,
                uv_set,
                before,
                mesh.positions.len()
            );
            if mesh.deform.is_some() {
                self.pose_at_rest(index)?;
            }
        }
        Ok(())
    }
}

/// A mesh's vertices split so that each has one tangent.
#[derive(Debug)]
pub(crate) struct Split {
    /// Each vertex's tangent, with the bitangent's sign in `w` as glTF's TANGENT has it.
    pub(crate) tangents: Vec<Vec4>,
    /// The vertex of the unsplit mesh that each vertex copies: the unsplit vertices keep their
    /// index, and the copies follow them.
    pub(crate) source: Vec<u32>,
    /// The triangles over the split vertices.
    pub(crate) indices: Vec<[u32; 3]>,
}

/// MikkTSpace tangents of the triangles `indices` over vertices with `positions`, unit
/// `normals` and texture coordinates `uvs` (glTF's, v running down the image), with the vertices
/// split where the corners that share one get different tangents (at a mirrored seam of the
/// texture, for instance); corners whose tangents are equal share one vertex.
pub(crate) fn mikktspace(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: &[Vec2],
    indices: &[[u32; 3]],
) -> Result<Split, String> {
    let vertex_count = positions.len();
    // Each corner may become a vertex of its own: their count must stay a 32-bit index.
    let most = vertex_count.saturating_add(indices.len().saturating_mul(3));
    if u32::try_from(most).is_err() {
        return Err(format!(
            "{} triangles over {vertex_count} vertices are too many to split for tangents",
            indices.len()
        ));
    }
    let mut corners =
        Corners { positions, normals, uvs, indices, tangents: vec![UNORIENTED; indices.len() * 3] };
    // The crate's error type has no variant: generation cannot fail.
    if let Err(e) = bevy_mikktspace::generate_tangents(&mut corners) {
        return Err(format!("MikkTSpace: {e}"));
    }

    let mut tangents = vec![UNORIENTED; vertex_count];
    let mut source: Vec<u32> = (0..vertex_count as u32).collect();
    let mut taken = vec![false; vertex_count];
    let mut copies: HashMap<(u32, [u32; 4]), u32> = HashMap::new();
    let mut split = Vec::with_capacity(indices.len());
    for (triangle, corner_tangents) in indices.iter().zip(corners.tangents.chunks_exact(3)) {
        let mut new = [0u32; 3];
        for ((slot, &vertex), &t) in new.iter_mut().zip(triangle).zip(corner_tangents) {
            let v = vertex as usize;
            *slot = if !taken[v] {
                taken[v] = true;
                tangents[v] = t;
                vertex
            } else if bits(tangents[v]) == bits(t) {
                vertex
            } else {
                *copies.entry((vertex, bits(t))).or_insert_with(|| {
                    source.push(vertex);
                    tangents.push(t);
                    (source.len() - 1) as u32
                })
            };
        }
        split.push(new);
    }
    Ok(Split { tangents, source, indices: split })
}

/// A tangent's bits, so that corners weld only where their tangents are identical.
fn bits(t: Vec4) -> [u32; 4] {
    t.to_array().map(f32::to_bits)
}

/// A tangent as the loader keeps it, read from TANGENT or generated: its direction of unit
/// length and its handedness ±1; `None` where either is unusable. A direction already of unit
/// length to rounding is kept as it is, so that tangents written out and read again are the same
/// bits (normalising a normalised vector again may move it by a unit in the last place).
pub(crate) fn clean_tangent(t: Vec4) -> Option<Vec4> {
    let dir = t.truncate();
    let dir = if (dir.length_squared() - 1.0).abs() <= 1e-6 { dir } else { dir.try_normalize()? };
    t.w.is_finite().then(|| dir.extend(if t.w < 0.0 { -1.0 } else { 1.0 }))
}

impl Split {
    /// Splits `mesh`'s vertices (each attribute, and a deforming mesh's rest geometry, morph
    /// targets and skin weights alike) and gives it the tangents, at rest too for a deforming
    /// mesh (which its owner must then pose again).
    pub(crate) fn apply(self, mesh: &mut Mesh) {
        let Split { tangents, source, indices } = self;
        let unsplit = mesh.positions.len();
        if source.len() != unsplit {
            copy_vertices(&mut mesh.positions, &source);
            if let Some(n) = &mut mesh.normals {
                copy_vertices(n, &source);
            }
            for uv in mesh.uvs.iter_mut().flatten() {
                copy_vertices(uv, &source);
            }
            if let Some(c) = &mut mesh.colors {
                copy_vertices(c, &source);
            }
            if let Some(d) = &mut mesh.deform {
                copy_vertices(&mut d.rest_positions, &source);
                if let Some(n) = &mut d.rest_normals {
                    copy_vertices(n, &source);
                }
                for target in &mut d.targets {
                    let deltas = [&mut target.positions, &mut target.normals, &mut target.tangents];
                    for deltas in deltas.into_iter().flatten() {
                        copy_vertices(deltas, &source);
                    }
                }
                if let Some(skin) = &mut d.skin {
                    let k = skin.influences;
                    copy_influences(&mut skin.vertex_joints, k, &source);
                    copy_influences(&mut skin.vertex_weights, k, &source);
                }
            }
            mesh.indices = indices;
        }
        if let Some(d) = &mut mesh.deform {
            d.rest_tangents = Some(tangents.clone());
        }
        mesh.tangents = Some(tangents);
    }
}

/// Replaces `values` (one per unsplit vertex) by one per split vertex.
fn copy_vertices<T: Copy>(values: &mut Vec<T>, source: &[u32]) {
    *values = source.iter().map(|&s| values[s as usize]).collect();
}

/// Replaces `values` (`k` per unsplit vertex) by `k` per split vertex.
fn copy_influences<T: Copy>(values: &mut Vec<T>, k: usize, source: &[u32]) {
    *values = source.iter().flat_map(|&s| &values[s as usize * k..][..k]).copied().collect();
}

/// The mesh as MikkTSpace reads it (triangles, corner by corner) and the tangents it writes.
struct Corners<'a> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    uvs: &'a [Vec2],
    indices: &'a [[u32; 3]],
    /// One per corner: triangle `f`'s corner `k` at `3 f + k`.
    tangents: Vec<Vec4>,
}

impl Corners<'_> {
    fn vertex(&self, face: usize, vert: usize) -> usize {
        self.indices[face][vert] as usize
    }
}

impl Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.indices.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.vertex(face, vert)].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.normals[self.vertex(face, vert)].to_array()
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        self.uvs[self.vertex(face, vert)].to_array()
    }

    fn set_tangent(&mut self, tangent: Option<TangentSpace>, face: usize, vert: usize) {
        // MikkTSpace's sign is that of texture space with v running up: glTF's v runs down the
        // image, which mirrors the bitangent (the tangent, along +u, is the same).
        let mirrored = tangent.map(|t| {
            let [x, y, z, w] = t.tangent_encoded();
            Vec4::new(x, y, z, -w)
        });
        self.tangents[face * 3 + vert] = mirrored.and_then(clean_tangent).unwrap_or(UNORIENTED);
    }
}
