//! Posing deforming meshes, as glTF 2.0 defines it (3.7.3): morph targets first (each attribute
//! plus the weighted sum of the targets' displacements), then the skin (linear blend skinning:
//! sum_i w_i (jointWorld_i x inverseBind_i), normals by the inverse transpose, tangents' xyz by
//! the matrix with the handedness kept). The arithmetic runs in f64 and rounds once, so that a
//! pose is the same whichever frame came before it.

use glam::{DMat3, DMat4, DVec3, Vec3};

use crate::animation::Animation;
use crate::scene::{Deform, Mesh};

impl Mesh {
    /// Whether a skin poses the mesh (its vertices are then in world space, and its instance
    /// does not follow its node).
    pub fn skinned(&self) -> bool {
        self.deform.as_ref().is_some_and(|d| d.skin.is_some())
    }
}

impl Deform {
    /// Whether `anim` changes the pose over time: it moves a joint of the skin, or animates the
    /// node's weights (of a mesh with morph targets).
    pub fn animated(&self, anim: &Animation) -> bool {
        if !self.targets.is_empty() && anim.animates_weights(self.node) {
            return true;
        }
        let Some(skin) = &self.skin else { return false };
        // Each node of the skeleton is looked at once, however many joints lie under it.
        let mut seen = std::collections::HashSet::new();
        for &joint in &skin.joints {
            let mut at = Some(joint);
            while let Some(n) = at.filter(|&n| seen.insert(n)) {
                if anim.nodes[n].motion.is_some() {
                    return true;
                }
                at = anim.nodes[n].parent;
            }
        }
        false
    }

    /// The morph target weights at time `t`: the animated ones, else the defaults.
    pub fn weights_at(&self, anim: Option<&Animation>, t: f64) -> Vec<f64> {
        let animated = anim.and_then(|a| a.weights(self.node, t));
        match animated {
            Some(w) if w.len() == self.targets.len() => w,
            _ => self.weights.iter().map(|&w| w as f64).collect(),
        }
    }

    /// Poses `mesh` (whose record this is) with morph target `weights` (one per target) and
    /// the joints' world transforms (`joint_world(node)`, unused without a skin), writing its
    /// positions, normals and tangents.
    pub fn pose(&self, weights: &[f64], joint_world: impl Fn(usize) -> DMat4, mesh: &mut Mesh) {
        let n = self.rest_positions.len();
        let mut positions: Vec<DVec3> = self.rest_positions.iter().map(|p| p.as_dvec3()).collect();
        let mut normals: Option<Vec<DVec3>> =
            self.rest_normals.as_ref().map(|ns| ns.iter().map(|v| v.as_dvec3()).collect());
        let mut tangents: Option<Vec<DVec3>> = self
            .rest_tangents
            .as_ref()
            .map(|ts| ts.iter().map(|v| v.truncate().as_dvec3()).collect());
        for (target, &w) in self.targets.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            let add = |out: &mut [DVec3], deltas: &Option<Vec<Vec3>>| {
                if let Some(d) = deltas {
                    for (o, d) in out.iter_mut().zip(d) {
                        *o += w * d.as_dvec3();
                    }
                }
            };
            add(&mut positions, &target.positions);
            if let Some(ns) = &mut normals {
                add(ns, &target.normals);
            }
            if let Some(ts) = &mut tangents {
                add(ts, &target.tangents);
            }
        }
        if let Some(skin) = &self.skin {
            let to_origin = DMat4::from_translation(-skin.origin);
            let joints: Vec<DMat4> = skin
                .joints
                .iter()
                .zip(&skin.inverse_binds)
                .map(|(&j, ib)| to_origin * joint_world(j) * *ib)
                .collect();
            let k = skin.influences;
            for v in 0..n {
                let mut m = DMat4::ZERO;
                for i in v * k..(v + 1) * k {
                    let w = skin.vertex_weights[i] as f64;
                    if w != 0.0 {
                        m += joints[skin.vertex_joints[i] as usize] * w;
                    }
                }
                if m == DMat4::ZERO {
                    m = to_origin; // Bound to nothing: the bind pose.
                }
                positions[v] = m.transform_point3(positions[v]);
                let linear = DMat3::from_mat4(m);
                if let Some(ns) = &mut normals {
                    ns[v] = normal_matrix(linear) * ns[v];
                }
                if let Some(ts) = &mut tangents {
                    ts[v] = linear * ts[v];
                }
            }
        }
        for (out, p) in mesh.positions.iter_mut().zip(&positions) {
            *out = p.as_vec3();
        }
        if let (Some(out), Some(ns), Some(rest)) = (&mut mesh.normals, &normals, &self.rest_normals)
        {
            for ((o, n), r) in out.iter_mut().zip(ns).zip(rest) {
                *o = n.try_normalize().map_or(*r, |n| n.as_vec3());
            }
        }
        if let (Some(out), Some(ts), Some(rest)) =
            (&mut mesh.tangents, &tangents, &self.rest_tangents)
        {
            for ((o, t), r) in out.iter_mut().zip(ts).zip(rest) {
                *o = t.try_normalize().map_or(*r, |t| t.as_vec3().extend(r.w));
            }
        }
    }
}

/// The matrix that carries normals under `m`: its inverse transpose, up to a positive factor
/// (the cofactor matrix, times the determinant's sign), defined even where `m` is singular.
fn normal_matrix(m: DMat3) -> DMat3 {
    let (a, b, c) = (m.x_axis, m.y_axis, m.z_axis);
    let cofactor = DMat3::from_cols(b.cross(c), c.cross(a), a.cross(b));
    if m.determinant() < 0.0 {
        cofactor * -1.0
    } else {
        cofactor
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{MorphTarget, Skin};
    use glam::Vec4;

    #[test]
    fn the_normal_matrix_is_the_inverse_transpose_up_to_scale() {
        let m = DMat3::from_cols(
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.5, 1.0, 0.0),
            DVec3::new(0.0, 0.0, -3.0),
        );
        let expect = m.inverse().transpose();
        let got = normal_matrix(m);
        let n = DVec3::new(0.3, -0.4, 0.8);
        let (a, b) = ((expect * n).normalize(), (got * n).normalize());
        assert!((a - b).length() < 1e-12, "{a} vs {b}");
    }

    #[test]
    fn morph_then_skin() {
        // One vertex at (1, 0, 0), a target moving it by (0, 1, 0); one joint translated by
        // (0, 0, 5) with an inverse bind of -1 along x.
        let deform = Deform {
            node: 0,
            node_name: "node 0".into(),
            rest_positions: vec![Vec3::X],
            rest_normals: Some(vec![Vec3::Z]),
            rest_tangents: Some(vec![Vec4::new(1.0, 0.0, 0.0, -1.0)]),
            targets: vec![MorphTarget {
                positions: Some(vec![Vec3::Y]),
                normals: None,
                tangents: None,
            }],
            weights: vec![0.5],
            skin: Some(Skin {
                index: 0,
                joints: vec![7],
                inverse_binds: vec![DMat4::from_translation(DVec3::NEG_X)],
                influences: 4,
                vertex_joints: vec![0; 4],
                vertex_weights: vec![1.0, 0.0, 0.0, 0.0],
                origin: DVec3::new(0.0, 0.0, 1.0),
                renormalised: 0,
            }),
        };
        let mut mesh = Mesh {
            positions: vec![Vec3::ZERO],
            normals: Some(vec![Vec3::ZERO]),
            tangents: Some(vec![Vec4::ZERO]),
            ..Default::default()
        };
        let world = |j: usize| {
            assert_eq!(j, 7);
            DMat4::from_translation(DVec3::new(0.0, 0.0, 5.0))
                * DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2)
        };
        deform.pose(&deform.weights_at(None, 0.0), world, &mut mesh);
        // Morphed (1, 0.5, 0); bind-relative (0, 0.5, 0); rotated (-0.5, 0, 0); moved
        // (-0.5, 0, 5); relative to the origin (-0.5, 0, 4).
        let p = mesh.positions[0];
        assert!((p - Vec3::new(-0.5, 0.0, 4.0)).length() < 1e-6, "{p}");
        assert!((mesh.normals.as_ref().unwrap()[0] - Vec3::Z).length() < 1e-6);
        let t = mesh.tangents.as_ref().unwrap()[0];
        assert!((t - Vec4::new(0.0, 1.0, 0.0, -1.0)).length() < 1e-6, "{t}");
    }

    #[test]
    fn a_non_uniform_scale_carries_normals_by_the_inverse_transpose() {
        // A joint scaling x by 2: a normal along (1, 1) leans toward y, (1, 2) / sqrt 5, where
        // the matrix itself would lean it toward x; a tangent along (1, 1) goes to (2, 1).
        let d = Vec3::new(1.0, 1.0, 0.0).normalize();
        let deform = Deform {
            rest_positions: vec![Vec3::ZERO],
            rest_normals: Some(vec![d]),
            rest_tangents: Some(vec![d.extend(-1.0)]),
            skin: Some(Skin {
                joints: vec![0],
                inverse_binds: vec![DMat4::IDENTITY],
                influences: 4,
                vertex_joints: vec![0; 4],
                vertex_weights: vec![1.0, 0.0, 0.0, 0.0],
                ..Default::default()
            }),
            ..Default::default()
        };
        let mut mesh = Mesh {
            positions: vec![Vec3::ZERO],
            normals: Some(vec![Vec3::ZERO]),
            tangents: Some(vec![Vec4::ZERO]),
            ..Default::default()
        };
        deform.pose(&[], |_| DMat4::from_scale(DVec3::new(2.0, 1.0, 1.0)), &mut mesh);
        let n = mesh.normals.as_ref().unwrap()[0];
        assert!((n - Vec3::new(1.0, 2.0, 0.0).normalize()).length() < 1e-6, "{n}");
        let t = mesh.tangents.as_ref().unwrap()[0];
        assert!((t - Vec3::new(2.0, 1.0, 0.0).normalize().extend(-1.0)).length() < 1e-6, "{t}");
    }
}
