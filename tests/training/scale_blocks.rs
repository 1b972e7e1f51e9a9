//! Block-partitioned training (issue 23): `partition` tiles the ground the cameras see and gives each block the frames
//! whose rays pass through it (checked here with the views' centre rays, computed independently); bad options are
//! refused by name; `train-blocks` trains every block in its own `msnerf train` process and resumes on a rerun; the
//! merged cloud keeps each point once, in the block whose core holds it.

use crate::common;
use glam::{DMat3, DVec3};
use msnerf::data::{load_dataset, LoadOptions, Split};
use msnerf::nerf::export::{export_points, ExportOptions};
use msnerf::nerf::run::LoadedRun;
use msnerf::output::pointcloud::PointCloud;
use msnerf::scale::merge::merge_clouds;
use msnerf::scale::partition::Block;
use msnerf::scale::partition::{partition, PartitionOptions};
use msnerf::scale::runner::{read_blocks, train_blocks, TrainBlocksOptions};
use msnerf::scale::{Blocks, ScaleError};
use msnerf::sim::{simulate, SceneDesc, SimOptions};
use std::path::Path;

fn textured(dir: &Path) {
    let scene = SceneDesc::load("ci-textured").expect("built-in scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

/// ci-textured's ground and objects seen by a nadir lawnmower flight (5 x 5 views, 25 m up, over 40 x 40 m) in a
/// projected CRS: parallel optical axes, so the ground height is given (the scene's `world_offset` z, 20 m).
fn grid_flight(dir: &Path) {
    let text = include_str!("../../configs/scenes/ci-textured.yaml");
    let cut = text.find("cameras:").expect("the scene has cameras");
    let yaml = format!(
        "{}crs: EPSG:32650\ncameras:\n  - grid: {{center: [0, 0], size: [40, 40], height: 25, rows: 5, cols: 5}}\n",
        &text[..cut]
    );
    let scene = SceneDesc::from_yaml(&yaml, "grid flight").expect("scene");
    simulate(&scene, &SimOptions::default(), dir).expect("simulate");
}

/// ci-textured partitioned 2 x 1 with 30 % overlap in a fresh temp folder: (folder, data, blocks folder, blocks).
fn two_blocks(tag: &str) -> (common::TempDir, std::path::PathBuf, std::path::PathBuf, msnerf::scale::Blocks) {
    let t = common::TempDir::new(tag);
    let data = t.path().join("data");
    textured(&data);
    let out = t.path().join("blocks");
    let o = PartitionOptions { blocks: [2, 1], overlap: 0.3, ground_z: None, overwrite: false };
    let blocks = partition(&data, &out, &o).expect("partition");
    (t, data, out, blocks)
}

/// `msnerf train` arguments for a few cheap steps of the tiny profile.
fn tiny_args(steps: &str) -> Vec<String> {
    ["--model", "tiny", "--max-steps", steps, "--rays-per-batch", "256", "--eval-pixels", "64"]
        .map(String::from)
        .to_vec()
}

#[test]
fn partition_tiles_the_ground_and_assigns_frames_by_their_rays() {
    let t = common::TempDir::new("partition");
    let data = t.path().join("data");
    grid_flight(&data);
    let out = t.path().join("blocks");
    let o = PartitionOptions { blocks: [2, 2], overlap: 0.2, ground_z: Some(20.0), overwrite: false };
    let b = partition(&data, &out, &o).expect("partition");
    assert_eq!(b.ground_z, 20.0);
    assert_eq!(b.rotation, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "a projected CRS is not levelled");
    assert_eq!(b.blocks.len(), 4);
    let src = load_dataset(&data, &LoadOptions::default()).expect("source");
    // Cores tile one box; grown bounds are the cores grown by 20 % of their size.
    let c = |ix: usize, iy: usize| b.blocks.iter().find(|k| k.index == [ix, iy]).expect("block").core;
    assert_eq!(c(0, 0)[1], c(1, 0)[0]);
    assert_eq!(c(0, 0)[3], c(0, 1)[2]);
    for k in &b.blocks {
        let (sx, sy) = (k.core[1] - k.core[0], k.core[3] - k.core[2]);
        let want = [k.core[0] - 0.2 * sx, k.core[1] + 0.2 * sx, k.core[2] - 0.2 * sy, k.core[3] + 0.2 * sy];
        for (g, w) in k.grown.iter().zip(want) {
            assert!((g - w).abs() < 1e-9, "{}: grown {:?}", k.name, k.grown);
        }
    }
    // Where each source frame's centre ray meets the ground, computed here from blocks.json's levelling.
    let r = DMat3::from_cols_array_2d(&b.rotation).transpose();
    let mut in_some_block = vec![false; src.frames.len()];
    for k in &b.blocks {
        let ds = load_dataset(&out.join(&k.name), &LoadOptions::default()).expect("block dataset loads");
        assert_eq!(ds.split_indices(Split::Train).len(), k.train_frames);
        let names: Vec<String> = ds.frames.iter().map(|f| f.name.clone()).collect();
        for (f, frame) in src.frames.iter().enumerate() {
            let p = &frame.c2w;
            let o = r * DVec3::new(p[0][3], p[1][3], p[2][3]);
            let d = r * -DVec3::new(p[0][2], p[1][2], p[2][2]);
            let hit = o + d * ((b.ground_z - o.z) / d.z);
            let inside = hit.x >= k.core[0] && hit.x <= k.core[1] && hit.y >= k.core[2] && hit.y <= k.core[3];
            let abs = data.join(&frame.name).display().to_string();
            let member = names.iter().any(|n| n.ends_with(&frame.name) || *n == abs);
            if inside {
                assert!(member, "{}: frame {} looks at its core but was left out", k.name, frame.name);
            }
            if member {
                in_some_block[f] = true;
                let bf = ds.frames.iter().find(|x| x.name.ends_with(&frame.name)).expect("member");
                assert_eq!(bf.split, frame.split, "{}: frame {} keeps its split", k.name, frame.name);
            }
        }
        assert!(ds.frames.len() < src.frames.len(), "{}: a block holds a part of the flight", k.name);
    }
    assert!(in_some_block.iter().all(|&x| x), "every frame trains some block");
}

#[test]
fn partition_refuses_bad_options_and_layouts_by_name() {
    let t = common::TempDir::new("partition-bad");
    let data = t.path().join("data");
    textured(&data);
    let opts = |blocks, overlap| PartitionOptions { blocks, overlap, ground_z: None, overwrite: false };
    let err = |o: PartitionOptions, name: &str| partition(&data, &t.path().join(name), &o).expect_err(name).to_string();
    assert!(err(opts([2, 2], 1.0), "o1").contains("--overlap"));
    assert!(err(opts([2, 2], -0.1), "o2").contains("--overlap"));
    assert!(err(opts([5, 5], 0.1), "o3").contains("more blocks than frames"));
    // Nadir cameras with parallel axes: no ground height, refused with the reason.
    let tf = data.join("transforms.json");
    let mut j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&tf).unwrap()).unwrap();
    for f in j["frames"].as_array_mut().unwrap() {
        for i in 0..3 {
            for k in 0..3 {
                f["transform_matrix"][i][k] = serde_json::json!(if i == k { 1.0 } else { 0.0 });
            }
        }
    }
    std::fs::write(&tf, j.to_string()).unwrap();
    let e = err(opts([2, 2], 0.1), "o4");
    assert!(e.contains("transforms.json") && e.contains("no ground area") && e.contains("--ground-z"), "{e}");
    for n in ["o1", "o2", "o3", "o4"] {
        assert!(!t.path().join(n).exists(), "nothing written for {n}");
    }
}

#[test]
fn train_blocks_trains_every_block_and_resumes() {
    let (t, _data, out, _) = two_blocks("train-blocks");
    let opts = |steps: &str| TrainBlocksOptions {
        exe: env!("CARGO_BIN_EXE_msnerf").into(),
        parallel: 2,
        devices: vec![],
        train_args: tiny_args(steps),
    };
    let runs = train_blocks(&out, &opts("4")).expect("train blocks");
    assert_eq!(runs.len(), 2);
    assert!(runs.iter().all(|r| !r.resumed && r.steps == Some(4)), "{runs:?}");
    // A rerun continues each block from its checkpoint instead of starting over.
    let again = train_blocks(&out, &opts("7")).expect("resume");
    assert!(again.iter().all(|r| r.resumed && r.steps == Some(7)), "{again:?}");
    // Merged cloud: each block's points cut to its core, every point owned by exactly one core.
    let g = common::gpu();
    let blocks = read_blocks(&out).expect("blocks.json");
    let export = |_: &Block, run: &Path| -> Result<PointCloud, ScaleError> {
        let mut r = LoadedRun::load(&g, run).map_err(|e| ScaleError::option("run", e.to_string()))?;
        export_points(&mut r, &ExportOptions::legacy(3000, 0.0, 1))
            .map_err(|e| ScaleError::option("export", e.to_string()))
    };
    let (cloud, stats) = merge_clouds(&out, &blocks, false, export).expect("merge");
    assert_eq!(stats.blocks.iter().map(|b| b.2).sum::<usize>(), cloud.len());
    assert!(stats.blocks.iter().any(|b| b.2 < b.1), "the overlaps were cut: {:?}", stats.blocks);
    let rows = blocks.rotation;
    let lo = |v: f64, first: bool| if first { f64::NEG_INFINITY } else { v };
    let hi = |v: f64, last: bool| if last { f64::INFINITY } else { v };
    for p in &cloud.positions {
        let q: Vec<f64> = (0..2).map(|i| (0..3).map(|j| rows[i][j] * p[j]).sum()).collect();
        let owners = blocks
            .blocks
            .iter()
            .filter(|b| {
                let [ix, iy] = b.index;
                q[0] >= lo(b.core[0], ix == 0)
                    && q[0] < hi(b.core[1], ix + 1 == blocks.grid[0])
                    && q[1] >= lo(b.core[2], iy == 0)
                    && q[1] < hi(b.core[3], iy + 1 == blocks.grid[1])
            })
            .count();
        assert_eq!(owners, 1, "point {p:?}");
    }
    merged_survey_takes_each_cell_from_its_owner(&g, &out, &blocks, t.path());
    render_blends_the_blocks_by_where_each_pixel_lies(&g, &out, &blocks, t.path());
    // An unfinished block: refused by name, or left out with `partial`.
    std::fs::remove_file(out.join("block_1_0/run/summary.json")).unwrap();
    let e = merge_clouds(&out, &blocks, false, export).expect_err("unfinished").to_string();
    assert!(e.contains("block_1_0") && e.contains("--partial"), "{e}");
    let (part, stats) = merge_clouds(&out, &blocks, true, export).expect("partial merge");
    assert_eq!((stats.missing.clone(), stats.blocks.len()), (vec!["block_1_0".to_string()], 1));
    assert!(part.len() < cloud.len());
    // The same through the CLI for the ortho: refused by name, or the finished block's cells with --partial.
    let ortho = t.path().join("partial_ortho.tif");
    let args = |partial: bool| {
        let mut v = vec!["export", "ortho", out.to_str().unwrap(), "--gsd", "2", "--out", ortho.to_str().unwrap()];
        if partial {
            v.push("--partial");
        }
        v.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let bin = env!("CARGO_BIN_EXE_msnerf");
    let refused = std::process::Command::new(bin).args(args(false)).output().expect("run msnerf");
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && text.contains("block_1_0") && text.contains("--partial"), "{text}");
    assert!(!ortho.exists(), "no product after a refusal");
    let text = common::msnerf(bin, &args(true).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(text.contains("left out") && text.contains("block_1_0"), "{text}");
    let o = msnerf::output::raster::geotiff_read::read_geotiff(&ortho).expect("partial ortho");
    let (w, h) = (o.grid.width, o.grid.height);
    let nodata = (0..w * h).filter(|&i| o.is_nodata(o.value(0, i % w, i / w))).count();
    assert!(nodata > 0 && nodata < w * h, "block_1_0's cells are nodata, block_0_0's are not ({nodata} of {})", w * h);
    let render = |partial: bool| {
        let dir = t.path().join(format!("partial_render_{partial}"));
        let mut v = vec!["render".to_string(), out.display().to_string(), "--out".into(), dir.display().to_string()];
        if partial {
            v.push("--partial".into());
        }
        std::process::Command::new(bin).args(&v).output().expect("run msnerf")
    };
    let refused = render(false);
    let text = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && text.contains("block_1_0") && text.contains("--partial"), "{text}");
    let partial = render(true);
    let text = String::from_utf8_lossy(&partial.stdout);
    assert!(partial.status.success() && text.contains("left out") && text.contains("block_1_0"), "{text}");

    // A broken block fails by name; the other still trains.
    std::fs::write(out.join("block_1_0/transforms.json"), "{").unwrap();
    std::fs::remove_dir_all(out.join("block_0_0/run")).unwrap();
    let e = train_blocks(&out, &opts("3")).expect_err("one block is broken").to_string();
    assert!(e.contains("block_1_0") && !e.contains("block_0_0:"), "{e}");
    assert!(out.join("block_0_0/run/summary.json").is_file(), "the healthy block trained");
}

/// The merged DSM and ortho over the blocks' cores: every cell as the block that owns it (found here from
/// blocks.json's levelling and half-open cores, the outer ones unbounded) renders it alone over the same grid, so
/// nothing is blended or doubled; both blocks contribute, and the other block's render differs in the overlap.
fn merged_survey_takes_each_cell_from_its_owner(g: &msnerf::gpu::Context, out: &Path, blocks: &Blocks, tmp: &Path) {
    use msnerf::nerf::survey::{SurveyGrid, SurveyOptions};
    use msnerf::nerf::survey_products::{export_survey, SurveyOutputs};
    use msnerf::output::raster::geotiff_read::read_geotiff;
    use msnerf::scale::merge_survey::{cores_bounds, flight_top, merge_survey};
    // Seven steps from one seed leave the two blocks' fields nearly alike: retrain one from another seed, so the
    // owner of a cell can be told apart.
    let block = out.join("block_1_0");
    std::fs::remove_dir_all(block.join("run")).unwrap();
    let (data, run) = (block.to_str().unwrap().to_string(), block.join("run").to_str().unwrap().to_string());
    let mut args = vec!["train", "--data", &data, "--out", &run, "--quiet", "--seed", "7"];
    let tiny = tiny_args("30");
    args.extend(tiny.iter().map(String::as_str));
    common::msnerf(env!("CARGO_BIN_EXE_msnerf"), &args);
    let b = cores_bounds(blocks);
    let grid = SurveyGrid::covering(b, (b[2] - b[0]) / 40.0, 1 << 20).expect("grid");
    let source = load_dataset(&blocks.source, &LoadOptions::default()).expect("source");
    let top = flight_top(blocks, &source).expect("the flight's camera height");
    let opts =
        SurveyOptions { consistency: None, max_spread_cells: None, refine: None, top: Some(top), ..Default::default() };
    let products = |tag: &str| SurveyOutputs {
        dsm: Some(tmp.join(format!("{tag}_dsm.tif"))),
        ortho: Some(tmp.join(format!("{tag}_ortho.tif"))),
        indices: vec![],
    };
    let merged = merge_survey(g, out, blocks, &grid, &opts, &products("merged"), false, |_, _, _| {}).expect("merge");
    assert_eq!(merged.blocks.len(), 2);
    assert!(merged.blocks.iter().all(|p| p.owned > 0 && p.valid > 0), "both blocks contribute: {:?}", merged.blocks);
    assert_eq!(merged.blocks.iter().map(|p| p.owned).sum::<usize>(), grid.cells(), "each cell owned once");
    let read = |tag: &str| {
        let o = products(tag);
        (read_geotiff(&o.dsm.unwrap()).expect("dsm"), read_geotiff(&o.ortho.unwrap()).expect("ortho"))
    };
    for blk in &blocks.blocks {
        let mut run = LoadedRun::load(g, &out.join(&blk.name).join("run")).expect("block run");
        export_survey(&mut run, &grid, &opts, &products(&blk.name), |_| {}).expect("block alone");
    }
    let (mdsm, mortho) = read("merged");
    let alone: Vec<_> = blocks.blocks.iter().map(|k| read(&k.name)).collect();
    assert_eq!((mdsm.grid.width, mdsm.grid.height), (grid.width, grid.height));
    let r = blocks.rotation;
    let nb = mortho.grid.bands;
    let (mut agree, mut compared, mut other_differs) = (0usize, 0usize, 0usize);
    for row in 0..grid.height {
        for col in 0..grid.width {
            let [x, y] = grid.centre(row, col);
            // Levelled x, y of the cell centre on the ground plane (levelled z = ground_z).
            let z = (blocks.ground_z - r[2][0] * x - r[2][1] * y) / r[2][2];
            let q = [0, 1].map(|i| r[i][0] * x + r[i][1] * y + r[i][2] * z);
            let owner = blocks
                .blocks
                .iter()
                .position(|k| {
                    let [ix, iy] = k.index;
                    (ix == 0 || q[0] >= k.core[0])
                        && (ix + 1 == blocks.grid[0] || q[0] < k.core[1])
                        && (iy == 0 || q[1] >= k.core[2])
                        && (iy + 1 == blocks.grid[1] || q[1] < k.core[3])
                })
                .expect("every cell has an owner");
            let same = |a: &msnerf::output::raster::geotiff_read::GeoRaster,
                        b: &msnerf::output::raster::geotiff_read::GeoRaster,
                        tol: f32| {
                (0..a.grid.bands).all(|band| {
                    let (u, v) = (a.value(band, col, row), b.value(band, col, row));
                    (a.is_nodata(u) && b.is_nodata(v)) || (u - v).abs() <= tol
                })
            };
            compared += 1;
            let (odsm, oortho) = &alone[owner];
            if same(&mdsm, odsm, 1e-2) && same(&mortho, oortho, 1e-3) {
                agree += 1;
            }
            let (xdsm, xortho) = &alone[1 - owner];
            if !same(&mdsm, xdsm, 1e-2) || !same(&mortho, xortho, 1e-3) {
                other_differs += 1;
            }
        }
    }
    assert!(nb >= 3);
    // The owner renders its rectangle, not the whole grid: ray origins differ in the last bits, which may flip a cell
    // at the accumulation floor.
    assert!(agree as f64 >= 0.99 * compared as f64, "{agree} of {compared} cells are the owner's");
    assert!(other_differs as f64 > 0.05 * compared as f64, "the blocks' renders differ ({other_differs} cells)");
}

/// `render BLOCKS`: each pixel is the blend of every block's render with weights computed here from blocks.json
/// (levelled surface point, cores with unbounded outer edges, a linear fade across each side's overlap margin,
/// weights floored at 1e-9), to 1e-4; the overlap is blended somewhere; and the CLI writes the views with a PSNR.
fn render_blends_the_blocks_by_where_each_pixel_lies(
    g: &msnerf::gpu::Context,
    out: &Path,
    blocks: &Blocks,
    tmp: &Path,
) {
    use msnerf::nerf::views::NovelView;
    use msnerf::scale::merge_render::{render_blocks, WorldView};
    let src = load_dataset(&blocks.source, &LoadOptions::default()).expect("source");
    let views: Vec<WorldView> = src
        .split_indices(Split::Eval)
        .iter()
        .take(2)
        .map(|&f| WorldView { name: src.frames[f].name.clone(), camera: src.frames[f].camera, c2w: src.frames[f].c2w })
        .collect();
    let mut merged = Vec::new();
    let stats = render_blocks(
        g,
        out,
        blocks,
        &views,
        false,
        1 << 30,
        |_, _, _| {},
        |k, rv| {
            assert_eq!(k, merged.len(), "views arrive in order");
            merged.push(rv);
            Ok(())
        },
    )
    .expect("render blocks");
    assert_eq!(stats.blocks.len(), 2);
    assert!(stats.blended_pixels > 0, "the overlap is blended somewhere");
    let r = DMat3::from_cols_array_2d(&blocks.rotation).transpose();
    let weight = |k: usize, p: [f64; 3]| -> f64 {
        let b = &blocks.blocks[k];
        let q = r * DVec3::from(p);
        let side = |v: f64, lo: f64, hi: f64, glo: f64, ghi: f64, first: bool, last: bool| -> f64 {
            if v < lo && !first {
                (1.0 - (lo - v) / (lo - glo)).clamp(0.0, 1.0)
            } else if v > hi && !last {
                (1.0 - (v - hi) / (ghi - hi)).clamp(0.0, 1.0)
            } else {
                1.0
            }
        };
        let [ix, iy] = b.index;
        let (c, gr) = (b.core, b.grown);
        side(q.x, c[0], c[1], gr[0], gr[1], ix == 0, ix + 1 == blocks.grid[0])
            * side(q.y, c[2], c[3], gr[2], gr[3], iy == 0, iy + 1 == blocks.grid[1])
    };
    let mut alone = Vec::new();
    for b in &blocks.blocks {
        let mut run = LoadedRun::load(g, &out.join(&b.name).join("run")).expect("block run");
        let novel: Vec<NovelView> = views.iter().map(|v| v.normalized(&run.transform)).collect();
        run.set_novel_views(&novel).expect("views");
        alone.push((0..views.len()).map(|j| run.render_novel_view(j).expect("render")).collect::<Vec<_>>());
    }
    let nb = src.n_bands();
    let mut worst = 0.0f64;
    for (j, v) in views.iter().enumerate() {
        let m = &merged[j];
        for i in 0..m.width * m.height {
            let ray = v.camera.ray_f64(&v.c2w, (i / m.width) as u32, (i % m.width) as u32);
            let (mut sum, mut wsum) = (vec![0.0f64; nb], 0.0f64);
            for (k, per_view) in alone.iter().enumerate() {
                let rv = &per_view[j];
                let d = rv.depth[i] as f64;
                let p = if rv.accumulation[i] >= 0.5 && d.is_finite() {
                    [0, 1, 2].map(|a| ray.origin[a] + ray.direction[a] * d)
                } else {
                    // The ground plane: levelled z = ground_z.
                    let (qo, qd) = (r * DVec3::from(ray.origin), r * DVec3::from(ray.direction));
                    let t = (blocks.ground_z - qo.z) / qd.z;
                    if qd.z.abs() > 1e-12 && t > 0.0 {
                        [0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a])
                    } else {
                        ray.origin
                    }
                };
                let w = weight(k, p).max(1e-9);
                for (s, c) in sum.iter_mut().zip(&rv.colour[i * nb..(i + 1) * nb]) {
                    *s += w * *c as f64;
                }
                wsum += w;
            }
            for (s, c) in sum.iter().zip(&m.colour[i * nb..(i + 1) * nb]) {
                worst = worst.max((*c as f64 - s / wsum).abs());
            }
        }
    }
    assert!(worst < 1e-4, "blend differs from the formula by {worst}");
    // Through the CLI: the eval views with their PSNR against the images.
    let dir = tmp.join("render");
    let text = common::msnerf(
        env!("CARGO_BIN_EXE_msnerf"),
        &["render", out.to_str().unwrap(), "--views", "eval", "--out", dir.to_str().unwrap()],
    );
    assert!(text.contains("PSNR") && text.contains("blended from more than one block"), "{text}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).expect("metrics.json")).unwrap();
    assert_eq!(metrics["views"].as_array().map(Vec::len), Some(src.split_indices(Split::Eval).len()));
    assert!(metrics["mean_psnr"].as_f64().is_some_and(|p| p.is_finite() && p > 5.0), "{metrics}");
    assert!(dir.join("contact_sheet.png").is_file());
}

/// SIGTERM (what Slurm sends before a time limit or a preemption) stops `msnerf train` with a checkpoint, so the
/// requeued task resumes instead of starting over.
#[test]
fn sigterm_saves_a_checkpoint_that_resumes() {
    let t = common::TempDir::new("sigterm");
    let data = t.path().join("data");
    textured(&data);
    let run = t.path().join("run");
    let exe = env!("CARGO_BIN_EXE_msnerf");
    let args = |steps: &str| [tiny_args(steps), vec!["--quiet".to_string()]].concat();
    let mut child = std::process::Command::new(exe)
        .args(["train", "--data", data.to_str().unwrap(), "--out", run.to_str().unwrap()])
        .args(args("100000"))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("start msnerf train");
    // Wait until steps are being logged, then ask it to stop as Slurm does.
    let metrics = run.join("metrics.jsonl");
    let t0 = std::time::Instant::now();
    while std::fs::read_to_string(&metrics).map_or(0, |m| m.lines().count()) < 3 {
        assert!(t0.elapsed().as_secs() < 120, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let kill = std::process::Command::new("kill").args(["-TERM", &child.id().to_string()]).status().expect("kill");
    assert!(kill.success());
    let status = child.wait().expect("wait");
    assert!(status.success(), "SIGTERM is a clean stop: {status}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).expect("summary")).expect("json");
    assert!(summary["stopped_early"].as_str().is_some_and(|s| s.contains("SIGTERM")), "{summary}");
    let steps = summary["steps"].as_u64().expect("steps");
    assert!(steps > 0 && run.join("checkpoints/latest.msnp").is_file());
    let more = (steps + 3).to_string();
    let resumed = std::process::Command::new(exe)
        .args(["train", "--data", data.to_str().unwrap(), "--out", run.to_str().unwrap(), "--resume"])
        .args(args(&more))
        .output()
        .expect("resume");
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).expect("summary")).expect("json");
    assert_eq!(summary["steps"].as_u64(), Some(steps + 3), "the resumed run continued from step {steps}");
}

/// `partition --slurm`'s job array: a script bash parses, one task per block, `--resume` once a block has a
/// checkpoint, SIGTERM before the time limit; run here as Slurm would run task 1 (the `#SBATCH` lines are comments
/// to bash), it trains that block.
#[test]
fn slurm_job_array_script_trains_its_task_block() {
    use msnerf::scale::slurm::{write_job_array, SlurmOptions};
    let (_t, _data, out, blocks) = two_blocks("slurm");
    let so = SlurmOptions {
        time: "01:30:00".into(),
        host_budget_bytes: 1 << 30,
        cpus_per_task: 2,
        gres: "gpu:1".into(),
        exe: env!("CARGO_BIN_EXE_msnerf").into(),
        train_args: tiny_args("3"),
    };
    let gib = write_job_array(&out, &blocks, &so).expect("script");
    assert_eq!(gib, 5, "the block's images (under 1 GiB) plus 4 GiB");
    let script = std::fs::read_to_string(out.join("slurm.sh")).expect("slurm.sh");
    for want in [
        "#SBATCH --array=0-1",
        "#SBATCH --gres=gpu:1",
        "#SBATCH --mem=5G",
        "#SBATCH --time=01:30:00",
        "#SBATCH --signal=B:TERM@120",
        "#SBATCH --requeue",
        "'block_0_0' 'block_1_0'",
        "--resume",
    ] {
        assert!(script.contains(want), "slurm.sh lacks {want}:\n{script}");
    }
    let parse = std::process::Command::new("bash").arg("-n").arg(out.join("slurm.sh")).status().expect("bash");
    assert!(parse.success(), "bash parses the script");
    let task = |id: &str| {
        std::process::Command::new("bash")
            .arg(out.join("slurm.sh"))
            .env("SLURM_ARRAY_TASK_ID", id)
            .output()
            .expect("run the task")
    };
    let r = task("1");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.join("block_1_0/run/summary.json").is_file() && !out.join("block_0_0/run").exists());
    // The requeued task finds the checkpoint and resumes.
    let r = task("1");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let bad = SlurmOptions { time: "soon".into(), ..so };
    assert!(write_job_array(&out, &blocks, &bad).unwrap_err().to_string().contains("--slurm-time"));
}

/// `partition --slurm` writes the job array into the blocks folder before it is renamed into place: the script
/// names the final folder, and a script that cannot be written leaves no blocks folder behind.
#[test]
fn partition_with_slurm_writes_the_script_before_the_folder_appears() {
    use msnerf::scale::partition::partition_with;
    use msnerf::scale::slurm::SlurmOptions;
    let t = common::TempDir::new("partition-slurm");
    let data = t.path().join("data");
    textured(&data);
    let o = PartitionOptions { blocks: [2, 1], overlap: 0.3, ground_z: None, overwrite: false };
    let so = SlurmOptions {
        time: "02:00:00".into(),
        host_budget_bytes: 1 << 30,
        cpus_per_task: 2,
        gres: String::new(),
        exe: env!("CARGO_BIN_EXE_msnerf").into(),
        train_args: tiny_args("3"),
    };
    let out = t.path().join("blocks");
    let (blocks, gib) = partition_with(&data, &out, &o, Some(&so)).expect("partition with a job array");
    assert_eq!((blocks.blocks.len(), gib), (2, Some(5)));
    let script = std::fs::read_to_string(out.join("slurm.sh")).expect("slurm.sh");
    let final_dir = std::path::absolute(&out).unwrap().display().to_string();
    assert!(script.contains(&format!("DIR='{final_dir}'")), "the script names the final folder:\n{script}");
    let bad_out = t.path().join("blocks-bad");
    let bad = SlurmOptions { time: "soon".into(), ..so };
    let e = partition_with(&data, &bad_out, &o, Some(&bad)).expect_err("bad time").to_string();
    assert!(e.contains("--slurm-time"), "{e}");
    let left: Vec<_> = std::fs::read_dir(t.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert!(!bad_out.exists(), "no blocks folder after a failed script: {left:?}");
    assert_eq!(left.len(), 2, "no staging folder left either: {left:?}");
}

/// `partition --slurm --slurm-time-from BENCH.json`: each task's limit is steps x ms per step x 1.25 + 15 min,
/// computed here by hand, from the measurement of the training's model and batch with the nearest band count at or
/// above the dataset's; a file without one is refused by name with the command that makes it.
#[test]
fn slurm_time_limit_comes_from_the_train_benchmark() {
    use msnerf::scale::slurm_time::{estimate, slurm_limit};
    let t = common::TempDir::new("slurm-time");
    let bench = t.path().join("bench.json");
    let row = |model: &str, bands: usize, rays: usize, ms: f64| serde_json::json!({"model": model, "bands": bands, "rays_per_batch": rays, "ms_per_step": ms, "device": "H200"});
    let rows = vec![
        row("nerfacto", 3, 4096, 4.28),
        row("nerfacto", 16, 4096, 9.0),
        row("nerfacto", 8, 4096, 6.0),
        row("nerfacto", 8, 8192, 11.0),
        row("tiny", 8, 256, 2.5),
    ];
    std::fs::write(&bench, serde_json::to_string(&rows).unwrap()).unwrap();
    let args = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    // 6 bands: the 8-band measurement at nerfacto's default batch (4096) and steps (30000).
    let e = estimate(&bench, &args(&["--model", "nerfacto"]), 6).expect("estimate");
    assert_eq!((e.steps, e.rays_per_batch, e.bench_bands, e.ms_per_step), (30_000, 4096, 8, 6.0));
    let minutes = (30_000.0f64 * 6.0 * 1.25 / 60_000.0 + 15.0).ceil() as u64; // 18.75 -> 19
    assert_eq!((e.minutes, e.limit.as_str()), (minutes, "00:19:00"));
    // Flags in either form, the last one winning; a long run crosses a day.
    let e = estimate(&bench, &args(&["--max-steps", "9", "--max-steps=2000000", "--rays-per-batch=8192"]), 8).unwrap();
    assert_eq!(e.minutes, (2_000_000.0f64 * 11.0 * 1.25 / 60_000.0 + 15.0).ceil() as u64);
    assert_eq!(e.limit, slurm_limit(e.minutes));
    assert_eq!(slurm_limit(473), "07:53:00");
    assert_eq!(slurm_limit(1440 + 61), "1-01:01:00");
    // No measurement with enough bands: refused, naming the file and the command to run.
    let err = estimate(&bench, &args(&["--model", "nerfacto"]), 32).expect_err("no 32-band row").to_string();
    assert!(err.contains("bench.json") && err.contains("--bands 32"), "{err}");
    std::fs::write(&bench, "{}").unwrap();
    assert!(estimate(&bench, &[], 3).expect_err("not a list").to_string().contains("bench.json"));
    // Through the CLI: the limit lands in the job script.
    std::fs::write(&bench, serde_json::to_string(&rows).unwrap()).unwrap();
    let data = t.path().join("data");
    textured(&data);
    let out = t.path().join("blocks");
    let bin = env!("CARGO_BIN_EXE_msnerf");
    let (d, o, b) = (data.to_str().unwrap(), out.to_str().unwrap(), bench.to_str().unwrap());
    let text = common::msnerf(
        bin,
        &[
            "partition",
            d,
            "--blocks",
            "2x1",
            "--out",
            o,
            "--slurm",
            "--slurm-time-from",
            b,
            "--",
            "--model",
            "tiny",
            "--rays-per-batch",
            "256",
            "--max-steps",
            "3000",
        ],
    );
    let minutes = (3000.0f64 * 2.5 * 1.25 / 60_000.0 + 15.0).ceil() as u64; // 15.16 -> 16
    assert_eq!(minutes, 16);
    assert!(text.contains("Slurm time limit 00:16:00"), "{text}");
    let script = std::fs::read_to_string(out.join("slurm.sh")).expect("slurm.sh");
    assert!(script.contains("#SBATCH --time=00:16:00"), "{script}");

    // Training arguments msnerf train would refuse, or that each block's command sets itself: refused before
    // anything is written (before, a bad flag went into slurm.sh, and a second --quiet failed every block).
    for (extra, says) in [("--bogus-flag", "--bogus-flag"), ("--quiet", "--quiet is set for each block")] {
        let out2 = t.path().join(format!("blocks{extra}"));
        let o2 = out2.to_str().unwrap();
        let r = std::process::Command::new(bin)
            .args(["partition", d, "--blocks", "2x1", "--out", o2, "--slurm", "--", "--model", "tiny", extra])
            .output()
            .expect("run msnerf");
        let text = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && text.contains("arguments after `--`") && text.contains(says), "{text}");
        assert!(!out2.exists(), "{extra}: nothing written");
    }
}

/// A dataset with sparse points (SfM tracks) partitions into blocks that load and train with depth supervision:
/// each block gets the source's points whose track holds one of its training frames (counted here from the source
/// file), with the track cut to the block's frames. (Before, every block pointed at the source's file, whose
/// tracks name frames the block lacks, and refused to load.)
#[test]
fn partition_cuts_the_sparse_points_to_each_blocks_frames() {
    use msnerf::data::sparse_points::read_sparse_points;
    use msnerf::sim::sparse::SparseOptions;
    let t = common::TempDir::new("partition-sparse");
    let data = t.path().join("data");
    let scene = SceneDesc::load("ci-textured").expect("built-in scene");
    let so = SimOptions {
        sparse_points: Some(SparseOptions { count: 2000, noise_m: 0.05, min_views: 2 }),
        ..Default::default()
    };
    simulate(&scene, &so, &data).expect("simulate");
    let out = t.path().join("blocks");
    let o = PartitionOptions { blocks: [2, 1], overlap: 0.3, ground_z: None, overwrite: false };
    let blocks = partition(&data, &out, &o).expect("partition");
    let src: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("sparse_points.json")).unwrap()).unwrap();
    let src = src["points"].as_array().expect("points").clone();
    let data_abs = std::path::absolute(&data).unwrap();
    for b in &blocks.blocks {
        let ds = load_dataset(&out.join(&b.name), &LoadOptions::default()).expect("block dataset");
        let path = ds.sparse_points_path.clone().expect("the block has sparse points");
        let points = read_sparse_points(&ds, &path).expect("every track frame is one of the block's frames");
        let train: std::collections::HashSet<String> =
            ds.split_indices(Split::Train).iter().map(|&f| ds.frames[f].name.clone()).collect();
        let want = src
            .iter()
            .filter(|p| {
                p["frames"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|n| train.contains(&data_abs.join(n.as_str().unwrap()).display().to_string()))
            })
            .count();
        assert!(want > 0, "{}: its frames see points", b.name);
        assert_eq!(points.len(), want, "{}", b.name);
    }
    // The blocks train with DS-NeRF depth from their points.
    let yaml = include_str!("../../configs/models/tiny.yaml").replace(
        "  distortion_mult: 0.002",
        "  distortion_mult: 0.002\n  depth: {loss: ds_nerf, source: sparse_points, mult: 1.0e-3, sigma: 0.2, ray_fraction: 0.25}",
    );
    assert!(yaml.contains("ds_nerf"), "the depth loss was added");
    let model = t.path().join("tiny-sfm.yaml");
    std::fs::write(&model, yaml).unwrap();
    let mut args = tiny_args("3");
    args[1] = model.display().to_string();
    let o =
        TrainBlocksOptions { exe: env!("CARGO_BIN_EXE_msnerf").into(), parallel: 1, devices: vec![], train_args: args };
    let runs = train_blocks(&out, &o).expect("the blocks train with depth supervision");
    assert!(runs.iter().all(|r| r.steps == Some(3)), "{runs:?}");
}

/// A hand-edited blocks.json whose blocks do not tile the grid once each is refused, naming the file and the block.
#[test]
fn blocks_json_must_tile_its_grid() {
    let (_t, _data, out, _) = two_blocks("blocks-json");
    let path = out.join("blocks.json");
    let good: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(read_blocks(&out).is_ok());
    let mut outside = good.clone();
    outside["blocks"][1]["index"] = serde_json::json!([5, 0]);
    std::fs::write(&path, outside.to_string()).unwrap();
    let e = read_blocks(&out).expect_err("index outside the grid").to_string();
    assert!(e.contains("blocks.json") && e.contains("block_1_0") && e.contains("2x1"), "{e}");
    let mut missing = good.clone();
    missing["blocks"].as_array_mut().unwrap().pop();
    std::fs::write(&path, missing.to_string()).unwrap();
    let e = read_blocks(&out).expect_err("a cell without a block").to_string();
    assert!(e.contains("blocks.json") && e.contains("every cell needs one"), "{e}");
}
