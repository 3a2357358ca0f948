//! The node tree: checks it is a forest (no cycles, one parent each), walks the default scene
//! composing transforms in f64, and emits mesh instances, cameras (scale removed) and
//! `KHR_lights_punctual` lights; also the default camera for files without one.

use ::gltf::json;
use glam::{DMat4, DQuat, DVec3, DVec4};
use json::camera::Type as CameraType;
use json::extensions::scene::khr_lights_punctual::{Light, Type as LightType};
use json::validation::Checked;

use super::json::raw_numbers;
use super::{fail, Context, Loader, SceneError};
use crate::budget;
use crate::scene::{Camera, Instance, Projection, PunctualKind, PunctualLight, Scene};

/// Vertical field of view of the camera added to files without one.
pub(crate) const DEFAULT_YFOV_DEGREES: f64 = 40.0;

impl Loader<'_> {
    /// Walks the default scene (`scene`, else scene 0, else every root node) depth first.
    pub(crate) fn load_nodes(&mut self) -> Result<(), SceneError> {
        let root = self.root;
        let parents = node_parents(root)?;
        self.parents = parents.clone();
        let roots: Vec<usize> = match root.scene {
            Some(s) => scene_roots(root, s.value(), &parents)?,
            None if !root.scenes.is_empty() => scene_roots(root, 0, &parents)?,
            None => (0..root.nodes.len()).filter(|&i| parents[i].is_none()).collect(),
        };
        let mut stack: Vec<(usize, DMat4)> =
            roots.iter().rev().map(|&r| (r, DMat4::IDENTITY)).collect();
        while let Some((index, parent_world)) = stack.pop() {
            let world =
                parent_world * self.local_transform(index).context(|| format!("node {index}"))?;
            if !world.is_finite() {
                return fail(format!("node {index}: world transform is not finite"));
            }
            self.visit(index, world)?;
            if let Some(children) = &root.nodes[index].children {
                stack.extend(children.iter().rev().map(|c| (c.value(), world)));
            }
        }
        Ok(())
    }

    /// A node's local transform from `matrix` or TRS, read in f64 from the raw JSON.
    pub(crate) fn local_transform(&self, index: usize) -> Result<DMat4, SceneError> {
        let node = &self.root.nodes[index];
        let raw = self.raw;
        let widen = |a: &[f32]| a.iter().map(|&v| v as f64).collect::<Vec<f64>>();
        if let Some(m) = &node.matrix {
            let m = raw_numbers::<16>(raw, "nodes", index, "matrix").unwrap_or_else(|| {
                let mut out = [0.0; 16];
                out.copy_from_slice(&widen(m));
                out
            });
            if m.iter().any(|v| !v.is_finite()) {
                return fail("matrix is not finite");
            }
            return Ok(DMat4::from_cols_array(&m));
        }
        let t = raw_numbers::<3>(raw, "nodes", index, "translation")
            .or_else(|| node.translation.map(|t| t.map(f64::from)))
            .unwrap_or([0.0; 3]);
        let r = raw_numbers::<4>(raw, "nodes", index, "rotation")
            .or_else(|| node.rotation.as_ref().map(|r| r.0.map(f64::from)))
            .unwrap_or([0.0, 0.0, 0.0, 1.0]);
        let s = raw_numbers::<3>(raw, "nodes", index, "scale")
            .or_else(|| node.scale.map(|s| s.map(f64::from)))
            .unwrap_or([1.0; 3]);
        if t.iter().chain(&r).chain(&s).any(|v| !v.is_finite()) {
            return fail("translation, rotation or scale is not finite");
        }
        let q = DQuat::from_array(r);
        let len = q.length();
        if len < 1e-6 {
            return fail(format!("rotation {r:?} is not a unit quaternion"));
        }
        Ok(DMat4::from_scale_rotation_translation(
            DVec3::from_array(s),
            q / len,
            DVec3::from_array(t),
        ))
    }

    fn visit(&mut self, index: usize, world: DMat4) -> Result<(), SceneError> {
        let root = self.root;
        let node = &root.nodes[index];
        let node_name = || match &node.name {
            Some(n) => format!("node {index} ({n})"),
            None => format!("node {index}"),
        };
        if let Some(mesh) = node.mesh {
            let mesh = mesh.value();
            let Some(gltf_mesh) = root.meshes.get(mesh) else {
                return fail(format!(
                    "node {index}: mesh {mesh} does not exist (the file has {} meshes)",
                    root.meshes.len()
                ));
            };
            let skin = node.skin.map(|s| s.value());
            // Each placement relative to the node (EXT_mesh_gpu_instancing), so that an animated
            // node can be placed again at any time. The placements are counted (from their
            // accessor) and charged before they are read.
            let instancing =
                node.extensions.as_ref().and_then(|e| e.others.get("EXT_mesh_gpu_instancing"));
            let placements = match instancing {
                Some(ext) => self
                    .gpu_instance_count(ext)
                    .context(|| format!("node {index}: EXT_mesh_gpu_instancing"))?,
                None => 1,
            };
            if let (Some(skin), Some(_)) = (skin, instancing) {
                return fail(format!(
                    "{}: a skinned mesh (skin {skin}) with EXT_mesh_gpu_instancing is not supported: the skin poses the mesh in world space, where the instances' placements have no meaning",
                    node_name()
                ));
            }
            let mut placed = Vec::new();
            for (prim, primitive) in gltf_mesh.primitives.iter().enumerate() {
                // A placement that deforms gets a mesh of its own; the others share theirs.
                let morphs = primitive.targets.as_ref().is_some_and(|t| !t.is_empty());
                let scene_mesh = if skin.is_some() || morphs {
                    self.deformed_mesh(index, &node_name(), mesh, prim, skin)?
                } else {
                    self.mesh_index(mesh, prim)?
                };
                if let Some(scene_mesh) = scene_mesh {
                    self.charge(
                        placements as u64,
                        |b| &mut b.instances,
                        || format!("node {index}"),
                    )?;
                    let triangles = self.meshes[scene_mesh].indices.len() as u64;
                    self.charge_scene(
                        budget::Line::Triangles,
                        placements as u64 * triangles,
                        || format!("node {index}, {placements} placements of {triangles}"),
                    )?;
                    placed.push(scene_mesh);
                }
            }
            let offsets = match instancing {
                Some(ext) => self
                    .gpu_instances(ext, DMat4::IDENTITY)
                    .context(|| format!("node {index}: EXT_mesh_gpu_instancing"))?,
                None => vec![DMat4::IDENTITY],
            };
            for scene_mesh in placed {
                // A skinned mesh is posed in world space (relative to its skin's origin): the
                // node's own transform does not place it (glTF 2.0, 3.7.3.3).
                let posed_by =
                    self.meshes[scene_mesh].deform.as_ref().and_then(|d| d.skin.as_ref());
                let world = posed_by.map_or(world, |s| DMat4::from_translation(s.origin));
                self.instances.extend(offsets.iter().map(|&offset| Instance {
                    mesh: scene_mesh,
                    node: index,
                    transform: world * offset,
                    offset,
                }));
            }
        } else if node.skin.is_some() {
            tracing::warn!("{}: has a skin but no mesh; ignored", node_name());
        }
        if let Some(camera) = node.camera {
            let camera = camera.value();
            let projection = camera_projection(root, camera).context(|| format!("node {index}"))?;
            let transform = rigid(world).unwrap_or_else(|| {
                tracing::warn!(
                    "{}: camera transform has no usable rotation; using the identity",
                    node_name()
                );
                DMat4::from_translation(world.w_axis.truncate())
            });
            let name = node
                .name
                .clone()
                .or_else(|| root.cameras[camera].name.clone())
                .unwrap_or_else(|| format!("camera {camera}"));
            self.cameras.push(Camera { name, node: Some(index), transform, projection });
        }
        if let Some(light) = node.extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref()) {
            let light = light.light.value();
            let lights = root
                .extensions
                .as_ref()
                .and_then(|e| e.khr_lights_punctual.as_ref())
                .map_or(&[][..], |l| &l.lights);
            let Some(def) = lights.get(light) else {
                return fail(format!(
                    "node {index}: light {light} does not exist (the file has {} lights)",
                    lights.len()
                ));
            };
            let kind = light_kind(def).context(|| format!("light {light}"))?;
            let direction = (world * DVec4::new(0.0, 0.0, -1.0, 0.0))
                .truncate()
                .try_normalize()
                .unwrap_or_else(|| {
                    tracing::warn!("{}: light direction is degenerate; using -z", node_name());
                    DVec3::NEG_Z
                });
            self.lights.push(PunctualLight {
                name: def
                    .name
                    .clone()
                    .or_else(|| node.name.clone())
                    .unwrap_or_else(|| format!("light {light}")),
                kind,
                intensity: glam::Vec3::from_array(def.color) * def.intensity,
                position: world.w_axis.truncate(),
                direction,
                range: def.range,
                node: Some(index),
            });
        }
        Ok(())
    }
}

impl Loader<'_> {
    /// World transforms of the instances `EXT_mesh_gpu_instancing` asks for: the node's world
    /// transform times each instance's TRS.
    /// How many placements an `EXT_mesh_gpu_instancing` object declares: the count of its first
    /// attribute's accessor (`gpu_instances` checks that the others agree).
    fn gpu_instance_count(&self, ext: &serde_json::Value) -> Result<usize, SceneError> {
        let attributes = ext.get("attributes").and_then(|a| a.as_object());
        let first = ["TRANSLATION", "ROTATION", "SCALE"]
            .iter()
            .find_map(|name| attributes.and_then(|a| a.get(*name)));
        match first.and_then(|a| a.as_u64()).and_then(|a| usize::try_from(a).ok()) {
            Some(acc) => Ok(self.accessor_info(acc)?.count),
            // Reading them gives the precise error.
            None => Ok(self.gpu_instances(ext, DMat4::IDENTITY)?.len()),
        }
    }

    fn gpu_instances(
        &self,
        ext: &serde_json::Value,
        world: DMat4,
    ) -> Result<Vec<DMat4>, SceneError> {
        let Some(attributes) = ext.get("attributes").and_then(|a| a.as_object()) else {
            return fail("no attributes");
        };
        let mut count: Option<usize> = None;
        let mut read = |name: &str, size: usize| -> Result<Option<Vec<f64>>, SceneError> {
            let Some(acc) = attributes.get(name) else { return Ok(None) };
            let Some(acc) = acc.as_u64().and_then(|a| usize::try_from(a).ok()) else {
                return fail(format!("{name} is not an accessor index"));
            };
            let (info, values) = self.read_f32(acc)?;
            if info.components() != size || matches!(info.ty, json::accessor::Type::Mat2) {
                return fail(format!(
                    "{name} accessor {acc} has the wrong type {}",
                    info.describe()
                ));
            }
            if let Some(bad) = values.iter().position(|v| !v.is_finite()) {
                return fail(format!("accessor {acc}: non-finite value at element {}", bad / size));
            }
            match count {
                Some(c) if c != info.count => {
                    return fail(format!(
                        "{name} accessor {acc} has {} elements, other attributes {c}",
                        info.count
                    ))
                }
                _ => count = Some(info.count),
            }
            Ok(Some(values.into_iter().map(f64::from).collect()))
        };
        let t = read("TRANSLATION", 3)?;
        let r = read("ROTATION", 4)?;
        let s = read("SCALE", 3)?;
        let Some(count) = count else {
            return fail("none of TRANSLATION, ROTATION, SCALE");
        };
        (0..count)
            .map(|i| {
                let t = t.as_ref().map_or(DVec3::ZERO, |t| DVec3::from_slice(&t[i * 3..]));
                let q = r.as_ref().map_or(DQuat::IDENTITY, |r| DQuat::from_slice(&r[i * 4..]));
                let s = s.as_ref().map_or(DVec3::ONE, |s| DVec3::from_slice(&s[i * 3..]));
                let len = q.length();
                if len < 1e-6 {
                    return fail(format!("instance {i}: rotation is not a unit quaternion"));
                }
                Ok(world * DMat4::from_scale_rotation_translation(s, q / len, t))
            })
            .collect()
    }
}

/// Each node's parent, after checking children exist, nobody has two parents and there is no
/// cycle.
pub(crate) fn node_parents(root: &json::Root) -> Result<Vec<Option<usize>>, SceneError> {
    let n = root.nodes.len();
    let mut parents: Vec<Option<usize>> = vec![None; n];
    for (i, node) in root.nodes.iter().enumerate() {
        for child in node.children.iter().flatten() {
            let c = child.value();
            if c >= n {
                return fail(format!(
                    "node {i}: child {c} does not exist (the file has {n} nodes)"
                ));
            }
            if c == i {
                return fail(format!("node {i}: is its own child (cycle in the node hierarchy)"));
            }
            if let Some(p) = parents[c] {
                return fail(format!("node {c}: has two parents, node {p} and node {i}"));
            }
            parents[c] = Some(i);
        }
    }
    // With one parent each, a node that no parentless node reaches lies on a cycle.
    let mut reached = vec![false; n];
    let mut stack: Vec<usize> = (0..n).filter(|&i| parents[i].is_none()).collect();
    while let Some(i) = stack.pop() {
        reached[i] = true;
        stack.extend(root.nodes[i].children.iter().flatten().map(|c| c.value()));
    }
    if let Some(i) = reached.iter().position(|r| !r) {
        return fail(format!("node {i}: is part of a cycle in the node hierarchy"));
    }
    Ok(parents)
}

/// The root nodes of scene `s`, checked.
fn scene_roots(
    root: &json::Root,
    s: usize,
    parents: &[Option<usize>],
) -> Result<Vec<usize>, SceneError> {
    let Some(scene) = root.scenes.get(s) else {
        return fail(format!(
            "scene {s}: does not exist (the file has {} scenes)",
            root.scenes.len()
        ));
    };
    let mut seen = vec![false; root.nodes.len()];
    let mut out = Vec::with_capacity(scene.nodes.len());
    for node in &scene.nodes {
        let i = node.value();
        if i >= root.nodes.len() {
            return fail(format!(
                "scene {s}: node {i} does not exist (the file has {} nodes)",
                root.nodes.len()
            ));
        }
        if let Some(p) = parents[i] {
            return fail(format!(
                "scene {s}: node {i} is not a root node (it is a child of node {p})"
            ));
        }
        if std::mem::replace(&mut seen[i], true) {
            return fail(format!("scene {s}: lists node {i} twice"));
        }
        out.push(i);
    }
    Ok(out)
}

fn camera_projection(root: &json::Root, index: usize) -> Result<Projection, SceneError> {
    let Some(camera) = root.cameras.get(index) else {
        return fail(format!(
            "camera {index}: does not exist (the file has {} cameras)",
            root.cameras.len()
        ));
    };
    match camera.type_ {
        Checked::Valid(CameraType::Perspective) => {
            let Some(p) = &camera.perspective else {
                return fail(format!(
                    "camera {index}: type is perspective but it has no perspective object"
                ));
            };
            if !(p.yfov > 0.0 && p.yfov < std::f32::consts::PI) {
                return fail(format!(
                    "camera {index}: yfov {} must lie strictly between 0 and pi",
                    p.yfov
                ));
            }
            Ok(Projection::Perspective { yfov: p.yfov })
        }
        Checked::Valid(CameraType::Orthographic) => {
            let Some(o) = &camera.orthographic else {
                return fail(format!(
                    "camera {index}: type is orthographic but it has no orthographic object"
                ));
            };
            for (name, v) in [("xmag", o.xmag), ("ymag", o.ymag)] {
                if !v.is_finite() || v == 0.0 {
                    return fail(format!("camera {index}: {name} {v} must be finite and not zero"));
                }
            }
            Ok(Projection::Orthographic { xmag: o.xmag, ymag: o.ymag })
        }
        Checked::Invalid => fail(format!("camera {index}: invalid type")),
    }
}

fn light_kind(light: &Light) -> Result<PunctualKind, SceneError> {
    if !light.color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return fail(format!("color {:?} must be finite and not negative", light.color));
    }
    if !(light.intensity.is_finite() && light.intensity >= 0.0) {
        return fail(format!("intensity {} must be finite and not negative", light.intensity));
    }
    if let Some(range) = light.range {
        if range.is_nan() || range <= 0.0 {
            return fail(format!("range {range} must be positive"));
        }
    }
    match light.type_ {
        Checked::Valid(LightType::Directional) => Ok(PunctualKind::Directional),
        Checked::Valid(LightType::Point) => Ok(PunctualKind::Point),
        Checked::Valid(LightType::Spot) => {
            let (inner, outer) =
                light.spot.as_ref().map_or((0.0, std::f32::consts::FRAC_PI_4), |s| {
                    (s.inner_cone_angle, s.outer_cone_angle)
                });
            let ok = inner.is_finite()
                && outer.is_finite()
                && inner >= 0.0
                && inner <= outer
                && outer > 0.0
                && outer <= std::f32::consts::FRAC_PI_2 + 1e-6;
            if !ok {
                return fail(format!(
                    "spot cone angles inner {inner}, outer {outer} must satisfy 0 <= inner <= outer <= pi/2"
                ));
            }
            Ok(PunctualKind::Spot { inner_cone: inner, outer_cone: outer })
        }
        Checked::Invalid => fail("invalid type"),
    }
}

/// The rigid part of a transform: rotation orthonormalised (its -z view axis kept, then +y),
/// scale and shear removed, translation kept. `None` if the axes are degenerate.
pub fn rigid(m: DMat4) -> Option<DMat4> {
    let z = m.z_axis.truncate().try_normalize()?;
    let y_in = m.y_axis.truncate();
    let y = (y_in - z * y_in.dot(z)).try_normalize()?;
    let x = y.cross(z);
    Some(DMat4::from_cols(
        x.extend(0.0),
        y.extend(0.0),
        z.extend(0.0),
        m.w_axis.truncate().extend(1.0),
    ))
}

/// A perspective camera looking down -z at the centre of the scene's bounds, far enough back
/// that the bounding sphere fits the vertical field of view (and so any image at least as wide
/// as tall).
pub(crate) fn default_camera(scene: &Scene) -> Camera {
    let yfov = DEFAULT_YFOV_DEGREES.to_radians();
    let (center, radius) = match scene.bounds() {
        Some((lo, hi)) => ((lo + hi) * 0.5, (hi - lo).length() * 0.5),
        None => (DVec3::ZERO, 1.0),
    };
    // A single point still needs a camera some way off it.
    let radius = radius.max(1e-6 * center.abs().max_element().max(1.0));
    let distance = radius / (yfov * 0.5).sin() * 1.05;
    Camera {
        name: "default".into(),
        node: None,
        transform: DMat4::from_translation(center + DVec3::new(0.0, 0.0, distance)),
        projection: Projection::Perspective { yfov: yfov as f32 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_removes_scale_and_keeps_translation() {
        let q = DQuat::from_rotation_y(0.7) * DQuat::from_rotation_x(-0.3);
        let t = DVec3::new(1e7, -2.5, 3.25);
        let m = DMat4::from_scale_rotation_translation(DVec3::new(2.0, 0.5, 3.0), q, t);
        let r = rigid(m).expect("non-degenerate");
        let expect = DMat4::from_rotation_translation(q, t);
        assert!(r.abs_diff_eq(expect, 1e-9), "{r:?} vs {expect:?}");
        assert!(rigid(DMat4::from_scale(DVec3::new(1.0, 1.0, 0.0))).is_none());
    }
}
