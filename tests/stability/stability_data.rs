//! Stability of the data path around the kernels: 16-bit extremes (0 and 65535) through the loader's scaling and
//! into the composite, UTM-sized world coordinates through pose normalisation, GPU ray generation and the renderer's
//! fp32 points back out to exported (PLY) world points, and degenerate cameras (zero focal length is a loader error
//! naming frame and key; parallel rays are fine).
//! Tolerances: loader values exact; GPU against the f64 twin |a-b| <= 1e-5 + 1e-4|b| (gradients per
//! tests/stability_support); world round trip 1 mm.

use crate::common;
use crate::data_support;
use crate::stability_support;
use common::gpu;
use data_support::{bands_json, frame, write_transforms, TempDir};
use msnerf::data::camera::{Camera, CameraModel, Distortion};
use msnerf::data::pose::{normalize_poses, Mat4};
use msnerf::data::{load_dataset, Band, DataError, LoadOptions};
use msnerf::gpu::{GpuBuffer, MemoryCategory};
use msnerf::nerf::kernels::{Geometry, RayBuffers};
use msnerf::nerf::rays::GpuCamera;
use msnerf::output::pointcloud::{read_ply, write_ply, PlyOptions};
use msnerf::output::PointCloud;
use serde_json::json;
use stability_support::*;

fn write_u16_tiff(path: &std::path::Path, w: u32, h: u32, data: &[u16]) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    let mut enc = tiff::encoder::TiffEncoder::new(f).expect("encoder");
    enc.write_image::<tiff::encoder::colortype::Gray16>(w, h, data).expect("write");
}

/// The loader's 16-bit scaling at its extremes: 0 -> 0.0 and 65535 -> 1.0 exactly with the default scale; a black
/// level above the raw value gives a negative target, a pixel_scale below the data's range gives targets above 1
/// (12-bit scale on 16-bit data: 16.0). Those targets, with colours saturated at 0 and 1, go through the composite's
/// loss and backward on the GPU: finite and equal to the f64 twin. Nothing divides by the target or takes its log.
#[test]
fn sixteen_bit_extremes_scale_exactly_and_render_finite() {
    let (w, h) = (6u32, 4u32);
    let pix: Vec<u16> = (0..w * h).map(|i| [0u16, 65535, 1, 65534, 32768, 4096][i as usize % 6]).collect();
    let mut all_targets = Vec::new();
    for (extra, want) in [
        (json!({}), [0.0f32, 1.0, 1.0 / 65535.0, 65534.0 / 65535.0, 32768.0 / 65535.0, 4096.0 / 65535.0]),
        (
            json!({"black_level": 4096, "pixel_scale": 61439}),
            [-4096.0 / 61439.0, 1.0, -4095.0 / 61439.0, 61438.0 / 61439.0, 28672.0 / 61439.0, 0.0],
        ),
        (
            json!({"pixel_scale": 4095}),
            [0.0, 65535.0 / 4095.0, 1.0 / 4095.0, 65534.0 / 4095.0, 32768.0 / 4095.0, 4096.0 / 4095.0],
        ),
    ] {
        let td = TempDir::new("stab16");
        for n in ["a", "b"] {
            write_u16_tiff(&td.path().join(format!("{n}.tif")), w, h, &pix);
        }
        let mut extra = extra;
        extra["bands"] = bands_json(1);
        write_transforms(td.path(), w, h, extra, vec![frame("a.tif", 0.0, "train"), frame("b.tif", 1.0, "eval")]);
        let ds = load_dataset(td.path(), &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
        let img = ds.read_frame(0).expect("frame");
        let got = img.band_f32(0);
        for (i, v) in got.iter().enumerate() {
            assert_eq!(*v, want[i % 6], "pixel {i} (raw {})", pix[i]);
        }
        all_targets.extend(got);
    }
    // Those targets through the composite, with colours exactly 0 and 1 (a saturated sigmoid).
    let g = gpu();
    let r = Render::new(&g);
    let (nr, n, bands) = (all_targets.len() / 3, 8, 3);
    let mut targets = Vec::new();
    for i in 0..nr {
        targets.extend_from_slice(&all_targets[3 * i..3 * i + 3]);
        targets.push(1.0);
    }
    let c = CompositeCase {
        rays: Rays::same(nr, [0.0, 0.0, 0.5], [0.3, -0.3, -0.9]),
        n,
        bands,
        edges: (0..nr).flat_map(|_| uniform_edges(n)).collect(),
        raw: (0..nr * n).map(|s| (s % 9) as f32 - 3.0).collect(),
        colours: (0..nr * n * bands).map(|i| (i % 2) as f32).collect(),
        targets,
        band_w: vec![1.0; bands],
        background: None,
        geo: Geometry { near: 0.05, far: 1000.0, contraction: true },
        scale: 0.01,
    };
    composite_matches_twin(&r, &c, "16-bit targets");
}

fn look_down_pose(x: f64, y: f64, z: f64, yaw: f64) -> Mat4 {
    // Camera looking straight down (-z), rotated by `yaw` about z (OpenGL camera axes in the columns).
    let (c, s) = (yaw.cos(), yaw.sin());
    [[c, -s, 0.0, x], [s, c, 0.0, y], [0.0, 0.0, 1.0, z], [0.0, 0.0, 0.0, 1.0]]
}

/// UTM-sized world coordinates (5e5 m east, 4e6 m north): f32 cannot even hold them to the metre (ulp(4e6) = 0.5 m),
/// so a pipeline that normalised in f32, or exported from f32 world coordinates, would lose the scene. Guards: pose
/// normalisation in f64 (`PoseTransform`, its inverse the true matrix inverse), the GPU works in the normalised
/// frame (|x| <= ~3, ulp 2.4e-7), exported points are mapped back in f64 and written as doubles. Checked end to end:
/// world poses -> normalised f32 camera table -> GPU ray_gen -> fp32 point at the rendered depth -> to_world ->
/// PLY -> read back, against the exact f64 ray/ground intersection: within 1 mm for a 100 m and a 5 km survey.
#[test]
fn utm_offsets_round_trip_to_exported_points_within_a_millimetre() {
    let g = gpu();
    let r = Render::new(&g);
    let cam = Camera {
        model: CameraModel::Pinhole,
        fx: 40.0,
        fy: 40.0,
        cx: 32.0,
        cy: 24.0,
        width: 64,
        height: 48,
        distortion: Distortion::default(),
    };
    for radius in [50.0f64, 2500.0] {
        let (e0, n0, z0) = (500_000.0, 4_000_000.0, 120.0);
        let poses: Vec<Mat4> = (0..8)
            .map(|i| {
                let a = i as f64 * std::f64::consts::TAU / 8.0;
                look_down_pose(e0 + radius * a.cos(), n0 + radius * a.sin(), z0 + 0.37 * i as f64, a)
            })
            .collect();
        let t = normalize_poses(&poses);
        let table: Vec<GpuCamera> = poses
            .iter()
            .map(|p| {
                let m = t.pose_to_normalized(p);
                GpuCamera::new(&cam, &[0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| m[r][c] as f32)))
            })
            .collect();
        let pixels: Vec<u32> = (0..64u32).flat_map(|i| [i % 8, (i * 7) % 48, (i * 13) % 64]).collect();
        let nr = pixels.len() / 3;
        let cams = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &table).expect("cams");
        let px = GpuBuffer::from_slice(&g, "pixels", MemoryCategory::Rays, &pixels).expect("pixels");
        let (o, d, norms) = (zeros(&g, "o", 3 * nr), zeros(&g, "d", 3 * nr), zeros(&g, "norms", nr));
        let mut rec = g.recorder("rays").expect("rec");
        r.k.ray_gen(&mut rec, &cams, &px, RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 }, &norms)
            .expect("ray_gen");
        rec.submit_and_wait().expect("submit");
        let (go, gd) = (g.download(&o).expect("o"), g.download(&d).expect("d"));
        assert_finite(&go, "origins");
        assert_finite(&gd, "directions");
        let mut exact = Vec::new();
        let mut positions = Vec::new();
        for i in 0..nr {
            let (ci, row, col) = (pixels[3 * i] as usize, pixels[3 * i + 1], pixels[3 * i + 2]);
            // Exact world point: the f64 world ray meets the ground z = 0.
            let wr = cam.ray_f64(&poses[ci], row, col);
            let tw = -wr.origin[2] / wr.direction[2];
            let pw: [f64; 3] = [0, 1, 2].map(|k| wr.origin[k] + tw * wr.direction[k]);
            // The renderer's depth along the normalised unit ray, in fp32 (scale x world distance), and its point.
            let depth = (tw * t.scale) as f32;
            let pn: [f32; 3] = [0, 1, 2].map(|k| go[3 * i + k] + gd[3 * i + k] * depth);
            exact.push(pw);
            positions.push(pn.map(|v| v as f64));
        }
        let band =
            Band { name: "nir".into(), center_nm: Some(840.0), fwhm_nm: None, pixel_scale: None, black_level: None };
        let mut cloud = PointCloud::new(positions, vec![band], vec![0.5; nr]).expect("cloud");
        cloud.to_world(&t);
        let td = TempDir::new("stab_utm");
        let path = td.path().join("cloud.ply");
        write_ply(&path, &cloud, &PlyOptions::default()).expect("write ply");
        let back = read_ply(&path).expect("read ply");
        let mut worst = 0.0f64;
        for (p, q) in back.positions.iter().zip(&exact) {
            let e = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
            worst = worst.max(e);
        }
        assert!(worst < 1e-3, "survey radius {radius} m: worst round-trip error {worst:e} m");
        // f32 world coordinates would not do: the same points rounded to f32 move by up to 0.25 m.
        let f32_err = exact.iter().map(|q| (q[1] as f32 as f64 - q[1]).abs()).fold(0.0, f64::max);
        assert!(f32_err > 1e-2, "the test's coordinates are big enough to matter ({f32_err})");
    }
}

/// Zero focal length: x = (u - cx) / 0 = Inf, directions Inf/Inf = NaN, every sample NaN. Guard: the loader rejects
/// fl_x / fl_y <= 0 with an error naming the file, the key and the frame (top-level values are reported for every
/// frame that inherits them).
#[test]
fn zero_focal_length_is_a_loader_error_naming_frame_and_key() {
    for (key, per_frame) in [("fl_x", true), ("fl_y", true), ("fl_x", false)] {
        let td = TempDir::new("stab_focal");
        let pix = vec![1000u16; 4 * 3];
        for n in ["a", "b"] {
            write_u16_tiff(&td.path().join(format!("{n}.tif")), 4, 3, &pix);
        }
        let mut frames = vec![frame("a.tif", 0.0, "train"), frame("b.tif", 1.0, "eval")];
        let mut extra = json!({"bands": bands_json(1)});
        if per_frame {
            frames[1][key] = json!(0.0);
        } else {
            extra[key] = json!(0.0);
        }
        write_transforms(td.path(), 4, 3, extra, frames);
        let e = load_dataset(td.path(), &LoadOptions::default()).expect_err("zero focal length must fail");
        let s = e.to_string();
        let all = e.flatten();
        assert!(all.iter().all(|x| matches!(x, DataError::NonPositiveFocal { .. })), "{all:?}");
        for part in ["transforms.json", key, if per_frame { "frame 1 (b.tif)" } else { "frame 0 (a.tif)" }] {
            assert!(s.contains(part), "error `{s}` does not name `{part}`");
        }
    }
}

/// Parallel rays (an orthographic-like camera: focal length 1e9 px, so every ray of a frame has the same direction
/// to fp32 precision) are fine: ray generation, sampling, weights and the composite stay finite and match the twin.
#[test]
fn parallel_rays_are_fine() {
    let g = gpu();
    let r = Render::new(&g);
    let cam = Camera {
        model: CameraModel::Pinhole,
        fx: 1e9,
        fy: 1e9,
        cx: 32.0,
        cy: 24.0,
        width: 64,
        height: 48,
        distortion: Distortion::default(),
    };
    let c2w: [[f32; 4]; 3] = [[1.0, 0.0, 0.0, 0.2], [0.0, 1.0, 0.0, -0.1], [0.0, 0.0, 1.0, 0.9]];
    let table = [GpuCamera::new(&cam, &c2w)];
    let pixels: Vec<u32> = (0..16u32).flat_map(|i| [0, i * 3, i * 4]).collect();
    let nr = pixels.len() / 3;
    let cams = GpuBuffer::from_slice(&g, "cams", MemoryCategory::Rays, &table).expect("cams");
    let px = GpuBuffer::from_slice(&g, "pixels", MemoryCategory::Rays, &pixels).expect("pixels");
    let (o, d, norms) = (zeros(&g, "o", 3 * nr), zeros(&g, "d", 3 * nr), zeros(&g, "norms", nr));
    let mut rec = g.recorder("rays").expect("rec");
    r.k.ray_gen(&mut rec, &cams, &px, RayBuffers { origins: &o, dirs: &d, n_rays: nr, ray_offset: 0 }, &norms)
        .expect("ray_gen");
    rec.submit_and_wait().expect("submit");
    let (go, gd) = (g.download(&o).expect("o"), g.download(&d).expect("d"));
    assert_finite(&gd, "directions");
    for i in 0..nr {
        let want = cam.ray_f32(&c2w, pixels[3 * i + 1], pixels[3 * i + 2]);
        let dz = [gd[3 * i], gd[3 * i + 1], gd[3 * i + 2] + 1.0];
        assert!(dz.iter().all(|v| v.abs() < 1e-7), "parallel: straight down the -z axis: {dz:?}");
        check_vals(&gd[3 * i..3 * i + 3], &f64s(&want.direction), "direction vs twin");
    }
    let rays = Rays {
        o: (0..nr).map(|i| [go[3 * i], go[3 * i + 1], go[3 * i + 2]]).collect(),
        d: (0..nr).map(|i| [gd[3 * i], gd[3 * i + 1], gd[3 * i + 2]]).collect(),
    };
    let geo = Geometry { near: 0.05, far: 1000.0, contraction: true };
    let n = 16;
    let (edges, pos) = r.sample_initial(&rays, geo, n, true);
    assert_finite(&pos, "positions");
    let c = CompositeCase {
        rays: rays.clone(),
        n,
        bands: 2,
        edges,
        raw: (0..nr * n).map(|s| (s % 6) as f32 - 2.0).collect(),
        colours: (0..nr * n * 2).map(|i| 0.1 + (i % 8) as f32 * 0.1).collect(),
        targets: (0..nr).flat_map(|_| [0.3, 0.6, 1.0]).collect(),
        band_w: vec![1.0, 1.0],
        background: None,
        geo,
        scale: 0.01,
    };
    composite_matches_twin(&r, &c, "parallel rays");
}
