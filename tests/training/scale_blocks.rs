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
use msnerf::scale::ScaleError;
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
    let (_t, _data, out, _) = two_blocks("train-blocks");
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
    // An unfinished block: refused by name, or left out with `partial`.
    std::fs::remove_file(out.join("block_1_0/run/summary.json")).unwrap();
    let e = merge_clouds(&out, &blocks, false, export).expect_err("unfinished").to_string();
    assert!(e.contains("block_1_0") && e.contains("--partial"), "{e}");
    let (part, stats) = merge_clouds(&out, &blocks, true, export).expect("partial merge");
    assert_eq!((stats.missing.clone(), stats.blocks.len()), (vec!["block_1_0".to_string()], 1));
    assert!(part.len() < cloud.len());

    // A broken block fails by name; the other still trains.
    std::fs::write(out.join("block_1_0/transforms.json"), "{").unwrap();
    std::fs::remove_dir_all(out.join("block_0_0/run")).unwrap();
    let e = train_blocks(&out, &opts("3")).expect_err("one block is broken").to_string();
    assert!(e.contains("block_1_0") && !e.contains("block_0_0:"), "{e}");
    assert!(out.join("block_0_0/run/summary.json").is_file(), "the healthy block trained");
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
