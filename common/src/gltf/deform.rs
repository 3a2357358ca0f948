//! Deforming placements: a node whose mesh has a skin or morph targets gets, per primitive, a
//! mesh of its own with a [`Deform`] record read and checked here (joints and weights,
//! inverse bind matrices, morph target displacements, default weights), posed at rest (the
//! node's weights, the joints' rest transforms) before it is placed.

use std::collections::HashMap;

use ::gltf::json;
use glam::{DMat4, Vec3};
use json::accessor::{ComponentType, Type};
use json::mesh::Semantic;
use json::validation::Checked;

use super::{fail, Context, Loader, SceneError};
use crate::scene::{Deform, MorphTarget, Skin};

/// How far a vertex's skin weights may sum from 1 before the loader warns. They are normalised
/// whatever their sum; this only keeps rounding (of floats, or of quantised weights whose
/// exporter rounded each one) from being reported.
const WEIGHT_SUM_TOLERANCE: f32 = 5e-3;

impl Loader<'_> {
    /// The scene mesh of primitive `prim` of glTF mesh `mesh` as node `node` (named `node_name`
    /// in messages) places it with its skin (`skin`) or morph targets: built anew, not shared
    /// with other placements, with its deformation record, posed at rest. `None` when the
    /// primitive has no triangles.
    pub(crate) fn deformed_mesh(
        &mut self,
        node: usize,
        node_name: &str,
        mesh: usize,
        prim: usize,
        skin: Option<usize>,
    ) -> Result<Option<usize>, SceneError> {
        let what = || format!("mesh {mesh} primitive {prim}");
        let Some((mut built, material)) = self.build_primitive(mesh, prim).context(what)? else {
            return Ok(None);
        };
        let mappings = self
            .variant_mappings(mesh, prim)
            .context(|| format!("{}: KHR_materials_variants", what()))?;
        let targets = self.morph_targets(mesh, prim, &built).context(what)?;
        let weights = self.default_weights(node, node_name, mesh, prim, targets.len())?;
        let skin = match skin {
            Some(s) => Some(
                self.read_skin(s, node_name, mesh, prim, built.positions.len())
                    .context(|| format!("{node_name}: skin {s}"))?,
            ),
            None => None,
        };
        let deform = Deform {
            node,
            node_name: node_name.to_string(),
            rest_positions: built.positions.clone(),
            rest_normals: built.normals.clone(),
            rest_tangents: built.tangents.clone(),
            targets,
            weights,
            skin,
        };
        built.deform = Some(Box::new(deform));
        self.meshes.push(built);
        self.mesh_materials.push(material);
        self.mesh_variant_materials.push(mappings);
        let index = self.meshes.len() - 1;
        self.pose_at_rest(index)?;
        Ok(Some(index))
    }

    /// Poses deforming mesh `index` at rest: its node's default weights, its joints' rest
    /// transforms.
    pub(crate) fn pose_at_rest(&mut self, index: usize) -> Result<(), SceneError> {
        let joints = self.meshes[index].deform.as_ref().and_then(|d| d.skin.as_ref());
        let joints = joints.map(|s| s.joints.clone()).unwrap_or_default();
        let mut worlds: HashMap<usize, DMat4> = HashMap::new();
        for j in joints {
            if let std::collections::hash_map::Entry::Vacant(e) = worlds.entry(j) {
                e.insert(self.rest_world(j)?);
            }
        }
        let mesh = &mut self.meshes[index];
        let Some(deform) = mesh.deform.take() else { return Ok(()) };
        deform.pose(&deform.weights_at(None, 0.0), |j| worlds[&j], mesh);
        mesh.deform = Some(deform);
        Ok(())
    }

    /// A node's rest world transform, through its ancestors (each node's computed once).
    fn rest_world(&mut self, node: usize) -> Result<DMat4, SceneError> {
        // The chain up to the first ancestor already known (or the root), then down again.
        let mut chain = Vec::new();
        let mut at = Some(node);
        while let Some(n) = at.filter(|n| !self.rest_worlds.contains_key(n)) {
            chain.push(n);
            at = self.parents.get(n).copied().flatten();
        }
        let mut world = at.map_or(DMat4::IDENTITY, |n| self.rest_worlds[&n]);
        for &n in chain.iter().rev() {
            world *= self.local_transform(n).context(|| format!("node {n}"))?;
            if !world.is_finite() {
                return fail(format!("node {n}: world transform is not finite"));
            }
            self.rest_worlds.insert(n, world);
        }
        Ok(world)
    }

    /// The primitive's morph targets, each displacement accessor checked against the vertex
    /// count before it is read. NORMAL and TANGENT displacements are read only where the mesh
    /// keeps normals and tangents.
    fn morph_targets(
        &self,
        mesh: usize,
        prim: usize,
        built: &crate::scene::Mesh,
    ) -> Result<Vec<MorphTarget>, SceneError> {
        let primitive = &self.root.meshes[mesh].primitives[prim];
        let Some(targets) = &primitive.targets else { return Ok(Vec::new()) };
        let n = built.positions.len();
        let read = |k: usize,
                    acc: Option<json::Index<json::Accessor>>,
                    name: &str,
                    wanted: bool|
         -> Result<Option<Vec<Vec3>>, SceneError> {
            let Some(acc) = acc.filter(|_| wanted).map(|a| a.value()) else { return Ok(None) };
            let what = || format!("morph target {k} {name}");
            let info = self.accessor_info(acc).context(what)?;
            if info.count != n {
                return fail(format!(
                    "{}: accessor {acc} has {} elements but the primitive has {n} vertices",
                    what(),
                    info.count
                ));
            }
            let deltas: Vec<Vec3> = self.read_vectors(acc, &[Type::Vec3], name).context(what)?;
            if let Some(bad) = deltas.iter().position(|d| !d.is_finite()) {
                return fail(format!(
                    "{}: accessor {acc}: non-finite value at element {bad}",
                    what()
                ));
            }
            Ok(Some(deltas))
        };
        let mut out = Vec::with_capacity(targets.len());
        for (k, t) in targets.iter().enumerate() {
            out.push(MorphTarget {
                positions: read(k, t.positions, "POSITION", true)?,
                normals: read(k, t.normals, "NORMAL", built.normals.is_some())?,
                tangents: read(k, t.tangents, "TANGENT", built.tangents.is_some())?,
            });
        }
        Ok(out)
    }

    /// The weights of `count` morph targets when nothing animates them: the node's `weights`,
    /// else the mesh's, else 0 (glTF 2.0, 3.7.2.2); a list of another length is an error.
    fn default_weights(
        &self,
        node: usize,
        node_name: &str,
        mesh: usize,
        prim: usize,
        count: usize,
    ) -> Result<Vec<f32>, SceneError> {
        if count == 0 {
            return Ok(Vec::new());
        }
        let check = |w: &Option<Vec<f32>>, whose: &str| -> Result<Option<Vec<f32>>, SceneError> {
            let Some(w) = w else { return Ok(None) };
            if w.len() != count {
                return fail(format!(
                    "{whose}: weights has {} values but mesh {mesh} primitive {prim} has {count} morph targets",
                    w.len()
                ));
            }
            if let Some(bad) = w.iter().find(|v| !v.is_finite()) {
                return fail(format!("{whose}: weight {bad} is not finite"));
            }
            Ok(Some(w.clone()))
        };
        let by_node = check(&self.root.nodes[node].weights, node_name)?;
        let by_mesh = check(&self.root.meshes[mesh].weights, &format!("mesh {mesh}"))?;
        Ok(by_node.or(by_mesh).unwrap_or_else(|| vec![0.0; count]))
    }

    /// Skin `index` as the primitive uses it: joints, inverse bind matrices, and every
    /// JOINTS_n / WEIGHTS_n set, checked (counts before reading, joint indices in range,
    /// weights not negative) and normalised per vertex.
    fn read_skin(
        &mut self,
        index: usize,
        node_name: &str,
        mesh: usize,
        prim: usize,
        n: usize,
    ) -> Result<Skin, SceneError> {
        let Some(skin) = self.root.skins.get(index) else {
            return fail(format!("does not exist (the file has {} skins)", self.root.skins.len()));
        };
        if skin.joints.is_empty() {
            return fail("joints is empty");
        }
        let nodes = self.root.nodes.len();
        let mut joints = Vec::with_capacity(skin.joints.len());
        for (i, j) in skin.joints.iter().enumerate() {
            let j = j.value();
            if j >= nodes {
                return fail(format!(
                    "joint {i} is node {j}, which does not exist (the file has {nodes} nodes)"
                ));
            }
            joints.push(j);
        }
        let count = joints.len();
        let inverse_binds = match skin.inverse_bind_matrices.map(|a| a.value()) {
            None => vec![DMat4::IDENTITY; count],
            Some(acc) => {
                let info = self.accessor_info(acc)?;
                if info.ty != Type::Mat4 || info.component != ComponentType::F32 {
                    return fail(format!(
                        "inverseBindMatrices accessor {acc} must be MAT4 of float, not {}",
                        info.describe()
                    ));
                }
                if info.count < count {
                    return fail(format!(
                        "inverseBindMatrices accessor {acc} has {} matrices for {count} joints",
                        info.count
                    ));
                }
                let (_, values) = self.read_f32(acc)?;
                if let Some(bad) = values.iter().position(|v| !v.is_finite()) {
                    return fail(format!(
                        "inverseBindMatrices accessor {acc}: non-finite value in matrix {}",
                        bad / 16
                    ));
                }
                values
                    .chunks_exact(16)
                    .take(count)
                    .map(|m| DMat4::from_cols_array(&std::array::from_fn(|i| m[i] as f64)))
                    .collect()
            }
        };
        let primitive = &self.root.meshes[mesh].primitives[prim];
        let attribute =
            |s: Semantic| primitive.attributes.get(&Checked::Valid(s)).map(|i| i.value());
        let mut sets = Vec::new();
        for set in 0u32.. {
            match (attribute(Semantic::Joints(set)), attribute(Semantic::Weights(set))) {
                (None, None) => break,
                (Some(j), Some(w)) => sets.push((set, j, w)),
                (Some(_), None) => {
                    return fail(format!(
                        "mesh {mesh} primitive {prim}: JOINTS_{set} without WEIGHTS_{set}"
                    ))
                }
                (None, Some(_)) => {
                    return fail(format!(
                        "mesh {mesh} primitive {prim}: WEIGHTS_{set} without JOINTS_{set}"
                    ))
                }
            }
        }
        if sets.is_empty() {
            return fail(format!(
                "mesh {mesh} primitive {prim} has no JOINTS_0 and WEIGHTS_0 to bind it to the skin"
            ));
        }
        for &(set, j, w) in &sets {
            let (ji, wi) = (self.accessor_info(j)?, self.accessor_info(w)?);
            let joints_ok = ji.ty == Type::Vec4
                && matches!(ji.component, ComponentType::U8 | ComponentType::U16)
                && !ji.normalized;
            if !joints_ok {
                return fail(format!(
                    "JOINTS_{set} accessor {j} must be VEC4 of unsigned byte or short, not {}",
                    ji.describe()
                ));
            }
            let weights_ok = wi.ty == Type::Vec4
                && (wi.component == ComponentType::F32
                    || (matches!(wi.component, ComponentType::U8 | ComponentType::U16)
                        && wi.normalized));
            if !weights_ok {
                return fail(format!(
                    "WEIGHTS_{set} accessor {w} must be VEC4 of float or normalized unsigned byte or short, not {}",
                    wi.describe()
                ));
            }
            for (name, acc, c) in [("JOINTS", j, ji.count), ("WEIGHTS", w, wi.count)] {
                if c != n {
                    return fail(format!(
                        "{name}_{set} accessor {acc} has {c} elements but the primitive has {n} vertices"
                    ));
                }
            }
        }
        let k = 4 * sets.len();
        let mut vertex_joints = vec![0u16; n * k];
        let mut vertex_weights = vec![0f32; n * k];
        for (s, &(set, j_acc, w_acc)) in sets.iter().enumerate() {
            let (_, js) = self.read_f32(j_acc)?;
            let (_, ws) = self.read_f32(w_acc)?;
            for v in 0..n {
                for c in 0..4 {
                    let (joint, weight) = (js[v * 4 + c] as usize, ws[v * 4 + c]);
                    if !(weight >= 0.0 && weight.is_finite()) {
                        return fail(format!(
                            "WEIGHTS_{set} accessor {w_acc}: vertex {v} has weight {weight} (weights must be finite and not negative)"
                        ));
                    }
                    // A joint index with weight 0 binds nothing; only one that counts must exist.
                    if joint >= count && weight > 0.0 {
                        return fail(format!(
                            "JOINTS_{set} accessor {j_acc}: vertex {v} names joint {joint}, out of range for the skin's {count} joints"
                        ));
                    }
                    let i = v * k + s * 4 + c;
                    vertex_joints[i] = if joint < count { joint as u16 } else { 0 };
                    vertex_weights[i] = weight;
                }
            }
        }
        let (mut off, mut unbound) = (0usize, 0usize);
        for ws in vertex_weights.chunks_exact_mut(k) {
            let sum: f32 = ws.iter().sum();
            if sum == 0.0 {
                unbound += 1;
                continue;
            }
            if (sum - 1.0).abs() > WEIGHT_SUM_TOLERANCE {
                off += 1;
            }
            if sum != 1.0 {
                ws.iter_mut().for_each(|w| *w /= sum);
            }
        }
        let what = || format!("{node_name}: skin {index}, mesh {mesh} primitive {prim}");
        if off > 0 {
            tracing::warn!(
                "{}: the joint weights of {off} of {n} vertices do not sum to one; normalised",
                what()
            );
        }
        if unbound > 0 {
            tracing::warn!(
                "{}: {unbound} of {n} vertices have joint weights all 0; they keep their bind-pose position",
                what()
            );
        }
        let origin = self.rest_world(joints[0])?.w_axis.truncate();
        Ok(Skin {
            index,
            joints,
            inverse_binds,
            influences: k,
            vertex_joints,
            vertex_weights,
            origin,
            renormalised: off + unbound,
        })
    }
}
