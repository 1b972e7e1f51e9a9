//! `field.coarse_to_fine` through a run: a loaded run renders with the grid levels its last step trained (the step
//! from `checkpoints/latest.json`), not with all of them; a run folder without that file is refused by name.

use crate::common::{gpu, simulate_ci_small, small_tiny_config, train_options, TempDir};
use msnerf::nerf::config::CoarseToFine;
use msnerf::nerf::run::LoadedRun;
use msnerf::nerf::trainer::train;

#[test]
fn loaded_run_renders_with_the_levels_its_last_step_trained() {
    let g = gpu();
    let tmp = TempDir::new("coarse_to_fine_run");
    let data = tmp.path().join("data");
    simulate_ci_small(&data);
    let mut cfg = small_tiny_config();
    cfg.trainer.max_steps = 30;
    cfg.trainer.rays_per_batch = 64;
    cfg.trainer.rays_per_chunk = 64;
    cfg.field.coarse_to_fine = Some(CoarseToFine { levels: 2, until_step: 100 });
    let run = tmp.path().join("run");
    train(&g, &train_options(&data, &run, cfg.clone(), 256)).expect("train");
    let state_path = run.join("checkpoints/latest.json");
    let state: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&state_path).unwrap()).unwrap();
    let step = state["step"].as_u64().expect("step");
    assert_eq!(step, 30);
    let want = cfg.field.active_levels_at(step);
    assert!(want > 2.0 && want < cfg.field.grid.n_levels as f32, "{want}: a fade still in progress");

    let mut loaded = LoadedRun::load(&g, &run).expect("load");
    assert_eq!(loaded.pipe.step, step);
    assert_eq!(loaded.pipe.model.field.grid.active_levels(), want);
    let view = loaded.render_view(0).expect("render");
    assert!(view.depth.iter().all(|d| d.is_finite()), "finite depths");
    // Rendering keeps the levels (the forward sets them from the pipeline's step).
    assert_eq!(loaded.pipe.model.field.grid.active_levels(), want);

    std::fs::remove_file(&state_path).unwrap();
    let e = LoadedRun::load(&g, &run).err().expect("no trainer state").to_string();
    assert!(e.contains("latest.json"), "{e}");
}
