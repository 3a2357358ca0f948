//! glTF animations: samplers (input times, output values, interpolation) and channels that target
//! a node's translation, rotation, scale or morph target weights, read into
//! [`crate::animation::Animation`]. Channels without a node (`KHR_animation_pointer`) are
//! skipped.

use glam::{DMat4, DQuat, DVec3};
use serde_json::Value;

use super::{fail, Context, Loader, SceneError};
use crate::animation::{AnimNode, Animation, Curve, Interpolation, NodeMotion, Trs};

fn index(v: &Value, key: &str) -> Option<usize> {
    v.get(key).and_then(Value::as_u64).map(|i| i as usize)
}

impl Loader<'_> {
    /// The file's node animation, `None` when no channel animates a node.
    pub(crate) fn load_animation(
        &self,
        animations: Option<&Value>,
        parents: &[Option<usize>],
    ) -> Result<Option<Animation>, SceneError> {
        let Some(Value::Array(animations)) = animations else { return Ok(None) };
        let n_nodes = self.root.nodes.len();
        let mut motions: Vec<Option<NodeMotion>> = vec![None; n_nodes];
        let mut weights: Vec<Option<Vec<Curve<f64>>>> = vec![None; n_nodes];
        let (mut start, mut end) = (f64::INFINITY, f64::NEG_INFINITY);
        for (a, anim) in animations.iter().enumerate() {
            let what = || format!("animation {a}");
            let samplers =
                anim.get("samplers").and_then(Value::as_array).cloned().unwrap_or_default();
            let channels =
                anim.get("channels").and_then(Value::as_array).cloned().unwrap_or_default();
            for (c, channel) in channels.iter().enumerate() {
                let what = || format!("{} channel {c}", what());
                let target = channel.get("target").cloned().unwrap_or(Value::Null);
                let Some(node) = index(&target, "node") else { continue };
                if node >= n_nodes {
                    return fail(format!("{}: node {node} does not exist", what()));
                }
                let path = target.get("path").and_then(Value::as_str).unwrap_or("");
                // A weights channel has one value per morph target of the node's mesh.
                let targets = if path == "weights" {
                    let targets = self.morph_target_count(node);
                    if targets == 0 {
                        tracing::warn!(
                            "{}: animates the weights of node {node}, whose mesh has no morph targets; ignored",
                            what()
                        );
                        continue;
                    }
                    targets
                } else {
                    1
                };
                let Some(s) = index(channel, "sampler") else {
                    return fail(format!("{}: no sampler", what()));
                };
                let Some(sampler) = samplers.get(s) else {
                    return fail(format!("{}: sampler {s} does not exist", what()));
                };
                let what_s = || format!("animation {a} sampler {s}");
                let interpolation = match sampler.get("interpolation").and_then(Value::as_str) {
                    None | Some("LINEAR") => Interpolation::Linear,
                    Some("STEP") => Interpolation::Step,
                    Some("CUBICSPLINE") => Interpolation::CubicSpline,
                    Some(other) => {
                        return fail(format!("{}: unknown interpolation {other}", what_s()))
                    }
                };
                let (Some(input), Some(output)) =
                    (index(sampler, "input"), index(sampler, "output"))
                else {
                    return fail(format!("{}: needs input and output accessors", what_s()));
                };
                let (_, times) = self.read_f32(input).context(|| format!("{}: input", what_s()))?;
                let times: Vec<f64> = times.iter().map(|&t| t as f64).collect();
                if times.is_empty() || times.iter().any(|t| !t.is_finite()) {
                    return fail(format!("{}: input times are empty or not finite", what_s()));
                }
                // Equal neighbours are harmless (sampling picks the last key at or before t);
                // decreasing times have no meaning.
                if times.windows(2).any(|w| w[1] < w[0]) {
                    return fail(format!("{}: input times decrease", what_s()));
                }
                let (info, values) =
                    self.read_f32(output).context(|| format!("{}: output", what_s()))?;
                let per_key = if interpolation == Interpolation::CubicSpline { 3 } else { 1 };
                let width = match path {
                    "translation" | "scale" => 3,
                    "rotation" => 4,
                    "weights" => 1,
                    other => return fail(format!("{}: unknown target path '{other}'", what())),
                };
                let expected = times.len() * per_key * targets;
                if info.components() != width || info.count != expected {
                    return fail(format!(
                        "{}: output has {} elements of {} components, expected {expected} of {width}{}",
                        what_s(),
                        info.count,
                        info.components(),
                        if path == "weights" {
                            format!(" (node {node}'s mesh has {targets} morph targets)")
                        } else {
                            String::new()
                        }
                    ));
                }
                if values.iter().any(|v| !v.is_finite()) {
                    return fail(format!("{}: output values are not finite", what_s()));
                }
                start = start.min(times[0]);
                end = end.max(times[times.len() - 1]);
                if path == "weights" {
                    // Key after key, `per_key` groups (in-tangents, values, out-tangents for
                    // CUBICSPLINE) of one value per target: one curve per target.
                    let curves = (0..targets)
                        .map(|m| Curve {
                            times: times.clone(),
                            values: values
                                .chunks_exact(targets)
                                .map(|group| group[m] as f64)
                                .collect(),
                            interpolation,
                        })
                        .collect();
                    weights[node] = Some(curves);
                    continue;
                }
                let motion = motions[node].get_or_insert_with(NodeMotion::default);
                let v3 =
                    |chunk: &[f32]| DVec3::new(chunk[0] as f64, chunk[1] as f64, chunk[2] as f64);
                match path {
                    "translation" | "scale" => {
                        let curve = Curve {
                            times,
                            values: values.chunks_exact(3).map(v3).collect(),
                            interpolation,
                        };
                        if path == "translation" {
                            motion.translation = Some(curve);
                        } else {
                            motion.scale = Some(curve);
                        }
                    }
                    _ => {
                        let mut keys: Vec<DQuat> = values
                            .chunks_exact(4)
                            .map(|q| {
                                DQuat::from_xyzw(q[0] as f64, q[1] as f64, q[2] as f64, q[3] as f64)
                            })
                            .collect();
                        if interpolation != Interpolation::CubicSpline {
                            for q in &mut keys {
                                if q.length() < 1e-6 {
                                    return fail(format!(
                                        "{}: a rotation key is not a unit quaternion",
                                        what_s()
                                    ));
                                }
                                *q = q.normalize();
                            }
                        }
                        motion.rotation = Some(Curve { times, values: keys, interpolation });
                    }
                }
            }
        }
        if motions.iter().all(Option::is_none) && weights.iter().all(Option::is_none) {
            return Ok(None);
        }
        let mut nodes = Vec::with_capacity(n_nodes);
        for (i, (motion, weights)) in motions.into_iter().zip(weights).enumerate() {
            let rest: DMat4 = self.local_transform(i).context(|| format!("node {i}"))?;
            let (scale, rotation, translation) = rest.to_scale_rotation_translation();
            nodes.push(AnimNode {
                parent: parents[i],
                rest,
                rest_trs: Trs { translation, rotation, scale },
                motion,
                weights,
            });
        }
        Ok(Some(Animation { nodes, start, end }))
    }

    /// How many morph targets node `node`'s mesh has (its first primitive with any; glTF
    /// requires every primitive to have as many), 0 without a mesh.
    fn morph_target_count(&self, node: usize) -> usize {
        let mesh = self.root.nodes[node].mesh.and_then(|m| self.root.meshes.get(m.value()));
        mesh.into_iter()
            .flat_map(|m| &m.primitives)
            .filter_map(|p| p.targets.as_ref())
            .map(Vec::len)
            .find(|&n| n > 0)
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use base64::Engine;

    use crate::gltf::{load_slice, NoFiles};

    /// A one-triangle scene whose node 0 has a translation channel with the given key times.
    fn scene_with_keys(times: [f32; 2], interpolation: &str) -> Vec<u8> {
        let mut bin: Vec<u8> = Vec::new();
        for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
            bin.extend(v.to_le_bytes());
        }
        for v in times {
            bin.extend(v.to_le_bytes());
        }
        for v in [0.0f32, 0.0, 0.0, 4.0, 0.0, 0.0] {
            bin.extend(v.to_le_bytes());
        }
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bin)
        );
        serde_json::json!({
            "asset": {"version": "2.0"},
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "buffers": [{"uri": uri, "byteLength": bin.len()}],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 36},
                {"buffer": 0, "byteOffset": 36, "byteLength": 8},
                {"buffer": 0, "byteOffset": 44, "byteLength": 24}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                 "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
                {"bufferView": 1, "componentType": 5126, "count": 2, "type": "SCALAR"},
                {"bufferView": 2, "componentType": 5126, "count": 2, "type": "VEC3"}
            ],
            "animations": [{
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
                "samplers": [{"input": 1, "output": 2, "interpolation": interpolation}]
            }]
        })
        .to_string()
        .into_bytes()
    }

    #[test]
    fn channels_pose_instances_at_any_time() {
        let mut scene = load_slice(&scene_with_keys([0.0, 2.0], "LINEAR"), &NoFiles).unwrap();
        assert!(scene.is_animated());
        let anim = scene.animation.as_ref().unwrap();
        assert_eq!((anim.start, anim.end), (0.0, 2.0));
        scene.set_time(0.5);
        assert_eq!(scene.instances[0].transform.w_axis.x, 1.0);
        scene.set_time(5.0);
        assert_eq!(scene.instances[0].transform.w_axis.x, 4.0, "clamped to the last key");
        let mut step = load_slice(&scene_with_keys([0.0, 2.0], "STEP"), &NoFiles).unwrap();
        step.set_time(1.9);
        assert_eq!(step.instances[0].transform.w_axis.x, 0.0);
    }

    #[test]
    fn lights_on_animated_nodes_move_with_them() {
        let mut json: serde_json::Value =
            serde_json::from_slice(&scene_with_keys([0.0, 2.0], "LINEAR")).unwrap();
        json["extensionsUsed"] = serde_json::json!(["KHR_lights_punctual"]);
        json["extensions"] = serde_json::json!({"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 1.0}]}});
        json["nodes"][0]["children"] = serde_json::json!([1]);
        json["nodes"] = serde_json::json!([json["nodes"][0].clone(),
            {"translation": [0.0, 1.0, 0.0], "extensions": {"KHR_lights_punctual": {"light": 0}}}]);
        let mut scene = load_slice(json.to_string().as_bytes(), &NoFiles).unwrap();
        assert!(scene.is_animated());
        scene.set_time(1.0);
        // The child light rides on its parent's translation (x = 2 at t = 1).
        let p = scene.lights[0].position;
        assert!((p - glam::DVec3::new(2.0, 1.0, 0.0)).length() < 1e-6, "{p}");
    }

    #[test]
    fn malformed_animations_are_errors_naming_the_sampler() {
        let err = load_slice(&scene_with_keys([1.0, 0.5], "LINEAR"), &NoFiles).unwrap_err();
        assert!(err.0.contains("animation 0 sampler 0") && err.0.contains("decrease"), "{err}");
        let err = load_slice(&scene_with_keys([0.0, 1.0], "BOUNCY"), &NoFiles).unwrap_err();
        assert!(err.0.contains("unknown interpolation BOUNCY"), "{err}");
        // CUBICSPLINE needs three values per key: two keys of plain values are refused.
        let err = load_slice(&scene_with_keys([0.0, 1.0], "CUBICSPLINE"), &NoFiles).unwrap_err();
        assert!(err.0.contains("expected 6"), "{err}");
    }
}
