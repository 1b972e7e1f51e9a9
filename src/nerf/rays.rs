//! Camera table for the `ray_gen` kernel: per image its intrinsics, distortion and normalised camera-to-world,
//! in the layout of `GpuCamera` in glsl/render/ray_gen.comp. The twin is `crate::data::camera::generate_ray`.

use crate::data::camera::{Camera, CameraModel};
use bytemuck::{Pod, Zeroable};

#[repr(C)]
#[derive(Copy, Clone, Debug, Default, Pod, Zeroable, PartialEq)]
pub struct GpuCamera {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// k1, k2, k3, k4, p1, p2
    pub dist: [f32; 6],
    pub model: u32,
    pub distorted: u32,
    /// 3x4 row-major camera-to-world in the normalised frame.
    pub c2w: [f32; 12],
}

impl GpuCamera {
    pub fn new(cam: &Camera, c2w: &[[f32; 4]; 3]) -> Self {
        let k = cam.intrinsics::<f32>();
        GpuCamera {
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            dist: k.dist,
            model: match cam.model {
                CameraModel::Pinhole => 0,
                CameraModel::OpenCv => 1,
                CameraModel::OpenCvFisheye => 2,
                CameraModel::Orthographic => 3,
            },
            distorted: u32::from(k.distorted),
            c2w: [
                c2w[0][0], c2w[0][1], c2w[0][2], c2w[0][3], c2w[1][0], c2w[1][1], c2w[1][2], c2w[1][3], c2w[2][0],
                c2w[2][1], c2w[2][2], c2w[2][3],
            ],
        }
    }
}
