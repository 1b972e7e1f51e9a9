//! The refined camera poses of a run with pose refinement, in the dataset's own world frame and units:
//! `RUN/camera_poses.json`, written with every checkpoint. Per training frame: its `file_path`, the refined and the
//! original `transform_matrix` (4x4 camera-to-world, OpenGL axes, as in transforms.json) and how far the refinement
//! moved the camera (world units) and turned it (degrees). A user can put the refined matrices back into a
//! transforms.json, as nerfstudio's `ns-export cameras` allows.

use crate::data::pose::{Mat4, PoseTransform};
use crate::data::Dataset;
use crate::maths::so3::rotate;

/// A normalised camera-to-world pose with correction p = [t, w] applied as the training rays see it: every ray
/// direction (a combination of the rotation columns) turned by exp(w), the centre moved by t.
pub fn corrected_pose(c2w: &Mat4, p: &[f64]) -> Mat4 {
    let w = [p[3], p[4], p[5]];
    let mut out = *c2w;
    for c in 0..3 {
        let col = rotate(w, [c2w[0][c], c2w[1][c], c2w[2][c]]);
        for (i, v) in col.iter().enumerate() {
            out[i][c] = *v;
        }
    }
    for i in 0..3 {
        out[i][3] = c2w[i][3] + p[i];
    }
    out
}

/// Angle in degrees between the rotation parts of two poses.
fn rotation_change_deg(a: &Mat4, b: &Mat4) -> f64 {
    // trace(A^T B) = 1 + 2 cos(angle)
    let tr: f64 = (0..3).map(|c| (0..3).map(|i| a[i][c] * b[i][c]).sum::<f64>()).sum();
    ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The camera_poses.json document for `frames` (dataset indices) given the pose slot (6 per dataset frame).
pub fn camera_poses_json(ds: &Dataset, t: &PoseTransform, frames: &[usize], poses: &[f32]) -> serde_json::Value {
    let entries: Vec<serde_json::Value> = frames
        .iter()
        .map(|&f| {
            let frame = &ds.frames[f];
            let p: Vec<f64> = poses[6 * f..6 * f + 6].iter().map(|&v| v as f64).collect();
            let refined = t.pose_to_world(&corrected_pose(&t.pose_to_normalized(&frame.c2w), &p));
            let moved = (0..3).map(|i| (refined[i][3] - frame.c2w[i][3]).powi(2)).sum::<f64>().sqrt();
            serde_json::json!({
                "file_path": frame.name,
                "transform_matrix": refined,
                "original_transform_matrix": frame.c2w,
                "translation_change": moved,
                "rotation_change_deg": rotation_change_deg(&frame.c2w, &refined),
            })
        })
        .collect();
    serde_json::json!({ "camera_model_frame": "OpenGL camera-to-world, the dataset's world frame and units", "frames": entries })
}
