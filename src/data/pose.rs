//! Pose normalisation as nerfstudio's dataparser does it (spec/nerfacto.md §2.1): orientation "up",
//! centre "poses", `auto_scale_poses`, all in f64 so UTM-sized coordinates (5e5, 4e6 m) keep sub-micrometre
//! precision through the round trip.
//!
//! `PoseTransform` serialises exactly like nerfstudio's `dataparser_transforms.json`:
//! `{"transform": [[..4..], [..4..], [..4..]], "scale": s}`, where normalised = s · (R · world + t).
//!
//! The maths is glam's f64 types ([`DVec3`], [`DMat3`], [`DMat4`]). Poses stay row-major `[[f64; 4]; 4]`
//! ([`Mat4`], the layout of `transform_matrix` in `transforms.json`) in the data types and file formats; glam's
//! matrices are column-major, so the two meet only through [`to_dmat4`] and [`from_dmat4`].

use glam::{DMat3, DMat4, DVec3};
use serde::{Deserialize, Serialize};

/// A 4x4 camera-to-world matrix (rows).
pub type Mat4 = [[f64; 4]; 4];

/// A row-major [`Mat4`] as a glam matrix (column-major): `to_dmat4(m).col(j)[i] == m[i][j]`.
pub fn to_dmat4(m: &Mat4) -> DMat4 {
    DMat4::from_cols_array_2d(m).transpose()
}

/// A glam matrix as a row-major [`Mat4`]; the inverse of [`to_dmat4`].
pub fn from_dmat4(m: &DMat4) -> Mat4 {
    m.transpose().to_cols_array_2d()
}

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

    /// `[R | t]` with scale `scale`.
    pub fn new(rotation: DMat3, translation: DVec3, scale: f64) -> PoseTransform {
        let rows = [0, 1, 2].map(|i| rotation.row(i).extend(translation[i]).to_array());
        PoseTransform { transform: rows, scale }
    }

    /// R (the 3x3 part of `transform`).
    pub fn rotation(&self) -> DMat3 {
        let m = &self.transform;
        DMat3::from_cols_array_2d(&[0, 1, 2].map(|i| [m[i][0], m[i][1], m[i][2]])).transpose()
    }

    /// t (the last column of `transform`).
    pub fn translation(&self) -> DVec3 {
        DVec3::from([0, 1, 2].map(|i| self.transform[i][3]))
    }

    /// Applies R⁻¹. Nerfstudio's Rodrigues formula has a `+1e-8` in a denominator, so R is orthonormal only
    /// to ~1e-8 and Rᵀ is not its inverse to the precision UTM coordinates need: use the true inverse,
    /// adj(R) v / det R (dividing once, where glam's `inverse` multiplies by a rounded 1 / det).
    fn rot_inv(&self, v: DVec3) -> DVec3 {
        let r = self.rotation();
        let [r0, r1, r2] = [0, 1, 2].map(|i| r.row(i));
        // The adjugate's columns are the cross products of R's rows.
        let adj = DMat3::from_cols(r1.cross(r2), r2.cross(r0), r0.cross(r1));
        (adj * v) / r0.dot(adj.x_axis)
    }

    fn normalized(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation() * p + self.translation())
    }

    fn world(&self, q: DVec3) -> DVec3 {
        self.rot_inv(q / self.scale - self.translation())
    }

    /// A world point in normalised coordinates.
    pub fn to_normalized(&self, p: [f64; 3]) -> [f64; 3] {
        self.normalized(p.into()).into()
    }

    /// A normalised point back in world coordinates.
    pub fn to_world(&self, q: [f64; 3]) -> [f64; 3] {
        self.world(q.into()).into()
    }

    /// A normalised-frame direction in the world frame: R⁻¹ v, unit length (directions take no scale or
    /// translation).
    pub fn direction_to_world(&self, v: [f64; 3]) -> [f64; 3] {
        normalize(self.rot_inv(v.into())).into()
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
        let m = to_dmat4(c2w);
        let map_dir = |v: DVec3| if forward { self.rotation() * v } else { self.rot_inv(v) };
        let p = m.w_axis.truncate();
        let q = if forward { self.normalized(p) } else { self.world(p) };
        let out = DMat4::from_cols(
            map_dir(m.x_axis.truncate()).extend(0.0),
            map_dir(m.y_axis.truncate()).extend(0.0),
            map_dir(m.z_axis.truncate()).extend(0.0),
            q.extend(1.0),
        );
        from_dmat4(&out)
    }

    /// Serialises as nerfstudio's `dataparser_transforms.json`.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("PoseTransform is plain numbers")
    }
}

/// `v / |v|`, or `v` itself when it is zero.
fn normalize(v: DVec3) -> DVec3 {
    let n = v.length();
    if n > 0.0 {
        v / n
    } else {
        v
    }
}

/// Rotation taking direction `a` to direction `b` (nerfstudio `rotation_matrix`, Rodrigues). For
/// opposite vectors nerfstudio perturbs `a` randomly; we rotate by π about a fixed perpendicular axis instead,
/// so the result is deterministic.
pub fn rotation_between(a: DVec3, b: DVec3) -> DMat3 {
    let a = normalize(a);
    let b = normalize(b);
    let v = a.cross(b);
    let c = a.dot(b);
    if c < -1.0 + 1e-8 {
        let helper = if a.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let k = normalize(a.cross(helper));
        // R = 2 k kᵀ − I (rotation by π about k).
        return DMat3::from_cols(k * k.x, k * k.y, k * k.z) * 2.0 - DMat3::IDENTITY;
    }
    let s2 = v.length_squared();
    // The cross-product matrix [v]×, column by column.
    let k = DMat3::from_cols(DVec3::new(0.0, v.z, -v.y), DVec3::new(-v.z, 0.0, v.x), DVec3::new(v.y, -v.x, 0.0));
    let f = (1.0 - c) / (s2 + 1e-8);
    DMat3::IDENTITY + k + (k * k) * f
}

/// `auto_orient_and_center_poses(method="up", center_method="poses")` followed by `auto_scale_poses`
/// (scale_factor 1): returns the transform; apply it with [`PoseTransform::pose_to_normalized`].
pub fn normalize_poses(poses: &[Mat4]) -> PoseTransform {
    if poses.is_empty() {
        return PoseTransform::IDENTITY;
    }
    let n = poses.len() as f64;
    let mut centre = DVec3::ZERO;
    let mut up = DVec3::ZERO;
    for p in poses {
        let m = to_dmat4(p);
        centre += m.w_axis.truncate() / n;
        up += m.y_axis.truncate();
    }
    let r = rotation_between(up, DVec3::Z);
    let mut t = PoseTransform::new(r, -(r * centre), 1.0);
    let mut max_abs: f64 = 0.0;
    for p in poses {
        let q = t.normalized(to_dmat4(p).w_axis.truncate());
        max_abs = max_abs.max(q.abs().max_element());
    }
    t.scale = if max_abs > 0.0 { 1.0 / max_abs } else { 1.0 };
    t
}

/// Inverse of a rigid transform (orthonormal rotation, translation): `[Rᵀ | −Rᵀ t]`.
pub fn rigid_inverse(m: &DMat4) -> DMat4 {
    let rt = DMat3::from_mat4(*m).transpose();
    let t = -(rt * m.w_axis.truncate());
    DMat4::from_cols(rt.x_axis.extend(0.0), rt.y_axis.extend(0.0), rt.z_axis.extend(0.0), t.extend(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A non-symmetric matrix survives the row-major ↔ glam round trip, and element (i, j) of the rows is
    /// column j, entry i, of the glam matrix.
    #[test]
    fn row_major_round_trip() {
        let m: Mat4 = [[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0], [9.0, 10.0, 11.0, 12.0], [13.0, 14.0, 15.0, 16.0]];
        let g = to_dmat4(&m);
        for (i, row) in m.iter().enumerate() {
            for (j, &x) in row.iter().enumerate() {
                assert_eq!(g.col(j)[i], x, "({i}, {j})");
                assert_eq!(g.row(i)[j], x, "({i}, {j})");
            }
        }
        assert_eq!(from_dmat4(&g), m);
        // A pose's translation is the last column, and glam transforms points the same way the rows do.
        let p = DVec3::new(0.5, -1.5, 2.0);
        let by_rows: [f64; 3] = [0, 1, 2].map(|i| m[i][0] * p.x + m[i][1] * p.y + m[i][2] * p.z + m[i][3]);
        assert_eq!(g.transform_point3(p).to_array(), by_rows);
    }

    fn rot_z(deg: f64) -> DMat3 {
        DMat3::from_rotation_z(deg.to_radians())
    }

    #[test]
    fn rigid_inverse_undoes_the_pose() {
        let r = DMat3::from_rotation_x(0.3) * rot_z(40.0);
        let m = DMat4::from_cols(
            r.x_axis.extend(0.0),
            r.y_axis.extend(0.0),
            r.z_axis.extend(0.0),
            DVec3::new(5e5, 4e6, 120.0).extend(1.0),
        );
        let id = rigid_inverse(&m) * m;
        assert!(id.abs_diff_eq(DMat4::IDENTITY, 1e-9), "{id}");
        let id = m * rigid_inverse(&m);
        assert!(id.abs_diff_eq(DMat4::IDENTITY, 1e-9), "{id}");
    }

    #[test]
    fn rotation_between_maps_a_onto_b() {
        for (a, b) in [
            (DVec3::new(0.2, -0.3, 0.9), DVec3::Z),
            (DVec3::new(1.0, 2.0, 3.0), DVec3::new(-3.0, 0.5, 1.0)),
            (DVec3::new(0.0, 0.0, -2.0), DVec3::Z),    // opposite
            (DVec3::new(1.0, 0.0, 0.0), DVec3::NEG_X), // opposite, the other helper axis
        ] {
            let r = rotation_between(a, b);
            assert!((r * a.normalize()).abs_diff_eq(b.normalize(), 1e-7), "{a} -> {b}: {}", r * a.normalize());
            assert!((r.determinant() - 1.0).abs() < 1e-7);
        }
    }

    /// The hand-written row-major code this module replaced, kept here to check the glam version equals it.
    mod by_hand {
        use super::super::Mat4;

        pub fn mat_mul(a: &Mat4, b: &Mat4) -> Mat4 {
            std::array::from_fn(|i| std::array::from_fn(|j| (0..4).map(|k| a[i][k] * b[k][j]).sum()))
        }

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

        pub fn rot_t(m: &[[f64; 4]; 3], v: [f64; 3]) -> [f64; 3] {
            let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
                - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
            let c = |r: usize, k: usize| {
                let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
                let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
                m[r1][k1] * m[r2][k2] - m[r1][k2] * m[r2][k1]
            };
            [0, 1, 2].map(|i| (c(0, i) * v[0] + c(1, i) * v[1] + c(2, i) * v[2]) / det)
        }
    }

    fn pose(r: DMat3, t: DVec3) -> Mat4 {
        from_dmat4(&DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), t.extend(1.0)))
    }

    #[test]
    fn glam_maths_equal_the_hand_written_maths() {
        let a = pose(DMat3::from_rotation_y(0.7) * rot_z(-25.0), DVec3::new(512_345.25, 4_123_456.5, 87.125));
        let b = pose(DMat3::from_rotation_x(-1.1), DVec3::new(-3.0, 2.5, 1e3));
        assert_eq!(from_dmat4(&(to_dmat4(&a) * to_dmat4(&b))), by_hand::mat_mul(&a, &b));
        assert_eq!(from_dmat4(&rigid_inverse(&to_dmat4(&a))), by_hand::rigid_inverse(&a));
        let poses = [a, b, pose(rot_z(90.0), DVec3::new(512_300.0, 4_123_400.0, 120.0))];
        let t = normalize_poses(&poses);
        let v = [512_345.25, 4_123_456.5, 87.125];
        let w = t.to_world(v);
        let by_hand = by_hand::rot_t(&t.transform, [0, 1, 2].map(|i| v[i] / t.scale - t.transform[i][3]));
        assert!(w.iter().zip(by_hand).all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs().max(1.0)), "{w:?} {by_hand:?}");
    }
}
