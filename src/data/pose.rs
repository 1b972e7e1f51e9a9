//! Pose normalisation as nerfstudio's dataparser does it (spec/nerfacto.md §2.1): orientation "up",
//! centre "poses", `auto_scale_poses`, all in f64 so UTM-sized coordinates (5e5, 4e6 m) keep sub-micrometre
//! precision through the round trip.
//!
//! `PoseTransform` serialises exactly like nerfstudio's `dataparser_transforms.json`:
//! `{"transform": [[..4..], [..4..], [..4..]], "scale": s}`, where normalised = s · (R · world + t).

use serde::{Deserialize, Serialize};

/// A 4x4 camera-to-world matrix (rows).
pub type Mat4 = [[f64; 4]; 4];

/// How camera poses are mapped into the normalised frame the field lives in (model config
/// `sampling.pose_normalization`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PoseNormalization {
    /// nerfstudio's dataparser: up-oriented, centred on the cameras, farthest camera at 1 ([`normalize_poses`]).
    #[default]
    Poses,
    /// The cube fitted to the ground the cameras see (`super::aerial`); when the layout is not aerial, `poses` with a
    /// warning that says why.
    Aerial,
    /// `aerial` when the cameras look down and their axes meet, `poses` otherwise.
    Auto,
}

/// World → normalised mapping: `p_n = scale · (R · p_w + t)` with `transform = [R | t]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseTransform {
    pub transform: [[f64; 4]; 3],
    pub scale: f64,
}

impl PoseTransform {
    pub const IDENTITY: PoseTransform =
        PoseTransform { transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]], scale: 1.0 };

    fn rot(&self, v: [f64; 3]) -> [f64; 3] {
        let m = &self.transform;
        [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
    }

    /// Applies R⁻¹. Nerfstudio's Rodrigues formula has a `+1e-8` in a denominator, so R is orthonormal only
    /// to ~1e-8 and Rᵀ is not its inverse to the precision UTM coordinates need: use the true inverse.
    fn rot_t(&self, v: [f64; 3]) -> [f64; 3] {
        let m = &self.transform;
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        let c = |r: usize, k: usize| {
            let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
            let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
            m[r1][k1] * m[r2][k2] - m[r1][k2] * m[r2][k1]
        };
        // inverse[i][j] = cofactor(j, i) / det
        [0, 1, 2].map(|i| (c(0, i) * v[0] + c(1, i) * v[1] + c(2, i) * v[2]) / det)
    }

    /// A world point in normalised coordinates.
    pub fn to_normalized(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rot(p);
        [0, 1, 2].map(|i| self.scale * (r[i] + self.transform[i][3]))
    }

    /// A normalised point back in world coordinates.
    pub fn to_world(&self, q: [f64; 3]) -> [f64; 3] {
        let v = [0, 1, 2].map(|i| q[i] / self.scale - self.transform[i][3]);
        self.rot_t(v)
    }

    /// A normalised-frame direction in the world frame: R⁻¹ v, unit length (directions take no scale or
    /// translation).
    pub fn direction_to_world(&self, v: [f64; 3]) -> [f64; 3] {
        normalize(self.rot_t(v))
    }

    /// A camera-to-world pose in normalised coordinates (rotation R·R_c, position mapped as a point).
    pub fn pose_to_normalized(&self, c2w: &Mat4) -> Mat4 {
        self.map_pose(c2w, true)
    }

    /// A normalised pose back in world coordinates.
    pub fn pose_to_world(&self, c2w: &Mat4) -> Mat4 {
        self.map_pose(c2w, false)
    }

    fn map_pose(&self, c2w: &Mat4, forward: bool) -> Mat4 {
        let mut out = [[0.0; 4]; 4];
        out[3] = [0.0, 0.0, 0.0, 1.0];
        for c in 0..3 {
            let col = [c2w[0][c], c2w[1][c], c2w[2][c]];
            let r = if forward { self.rot(col) } else { self.rot_t(col) };
            for i in 0..3 {
                out[i][c] = r[i];
            }
        }
        let p = [c2w[0][3], c2w[1][3], c2w[2][3]];
        let q = if forward { self.to_normalized(p) } else { self.to_world(p) };
        for i in 0..3 {
            out[i][3] = q[i];
        }
        out
    }

    /// Serialises as nerfstudio's `dataparser_transforms.json`.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("PoseTransform is plain numbers")
    }
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        v.map(|x| x / n)
    } else {
        v
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Rotation taking direction `a` to direction `b` (nerfstudio `rotation_matrix`, Rodrigues). For
/// opposite vectors nerfstudio perturbs `a` randomly; we rotate by π about a fixed perpendicular axis instead,
/// so the result is deterministic.
pub fn rotation_between(a: [f64; 3], b: [f64; 3]) -> [[f64; 3]; 3] {
    let a = normalize(a);
    let b = normalize(b);
    let v = cross(a, b);
    let c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    if c < -1.0 + 1e-8 {
        let helper = if a[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        let k = normalize(cross(a, helper));
        // R = 2 k kᵀ − I (rotation by π about k).
        let mut r = [[0.0; 3]; 3];
        for (i, row) in r.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = 2.0 * k[i] * k[j] - if i == j { 1.0 } else { 0.0 };
            }
        }
        return r;
    }
    let s2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let k = [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]];
    let f = (1.0 - c) / (s2 + 1e-8);
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let kk: f64 = (0..3).map(|m| k[i][m] * k[m][j]).sum();
            r[i][j] = if i == j { 1.0 } else { 0.0 } + k[i][j] + kk * f;
        }
    }
    r
}

/// `auto_orient_and_center_poses(method="up", center_method="poses")` followed by `auto_scale_poses`
/// (scale_factor 1): returns the transform; apply it with [`PoseTransform::pose_to_normalized`].
pub fn normalize_poses(poses: &[Mat4]) -> PoseTransform {
    if poses.is_empty() {
        return PoseTransform::IDENTITY;
    }
    let n = poses.len() as f64;
    let mut centre = [0.0; 3];
    let mut up = [0.0; 3];
    for p in poses {
        for i in 0..3 {
            centre[i] += p[i][3] / n;
            up[i] += p[i][1];
        }
    }
    let r = rotation_between(up, [0.0, 0.0, 1.0]);
    let rc = [0, 1, 2].map(|i| r[i][0] * centre[0] + r[i][1] * centre[1] + r[i][2] * centre[2]);
    let mut t = PoseTransform { transform: [0, 1, 2].map(|i| [r[i][0], r[i][1], r[i][2], -rc[i]]), scale: 1.0 };
    let mut max_abs: f64 = 0.0;
    for p in poses {
        let q = t.to_normalized([p[0][3], p[1][3], p[2][3]]);
        for x in q {
            max_abs = max_abs.max(x.abs());
        }
    }
    t.scale = if max_abs > 0.0 { 1.0 / max_abs } else { 1.0 };
    t
}

/// Inverse of a rigid transform (orthonormal rotation, translation).
pub fn rigid_inverse(m: &Mat4) -> Mat4 {
    let mut r = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = m[j][i];
        }
        r[i][3] = -(0..3).map(|k| m[k][i] * m[k][3]).sum::<f64>();
    }
    r[3][3] = 1.0;
    r
}

/// Matrix product of two 4x4 matrices.
pub fn mat_mul(a: &Mat4, b: &Mat4) -> Mat4 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..4).map(|k| a[i][k] * b[k][j]).sum()))
}
