//! Model configs that would crash or train garbage are refused by `ModelConfig::validate` (as loading a profile
//! or a sweep cell runs it), naming the key: values a YAML file can hold but the trainer cannot use (a zero
//! evaluation interval divides by zero, a NaN density or loss weight poisons every step, a grid resolution whose
//! cell count overflows, an MLP shape the kernels do not have). Found by a bad-input audit (2026-11-28).

use msnerf::nerf::config::ModelConfig;

type Edit = fn(&mut ModelConfig);

#[test]
fn unusable_model_values_are_refused_by_key() {
    let base = ModelConfig::resolve("tiny").expect("tiny");
    base.validate().expect("the profile itself is valid");
    let cases: Vec<(Edit, &[&str])> = vec![
        (|c| c.trainer.steps_per_save = 0, &["trainer.steps_per_save", "got 100 and 0"]),
        (|c| c.trainer.steps_per_eval = 0, &["trainer.steps_per_eval"]),
        (|c| c.field.average_init_density = f32::NAN, &["field.average_init_density", "NaN"]),
        (|c| c.field.average_init_density = -1.0, &["field.average_init_density"]),
        (|c| c.loss.distortion_mult = f32::NAN, &["loss.distortion_mult"]),
        (|c| c.loss.interlevel_mult = -1.0, &["loss.interlevel_mult"]),
        (|c| c.loss.band_weights = Some(vec![1.0, f32::NAN, 1.0]), &["loss.band_weights[1]"]),
        (|c| c.loss.band_weights = Some(vec![1.0, -2.0, 1.0]), &["loss.band_weights[1]"]),
        (|c| c.loss.band_weights = Some(vec![0.0; 3]), &["loss.band_weights", "at least one band"]),
        (|c| c.optimizer.fields.lr = f64::NAN, &["optimizer.fields", "lr must be > 0"]),
        (|c| c.optimizer.proposals.lr_final = -1.0, &["optimizer.proposals", "lr_final"]),
        (|c| c.optimizer.fields.eps = 0.0, &["optimizer.fields.eps"]),
        (|c| c.field.hidden_dim = 0, &["field (density MLP", "width", "got 0"]),
        (|c| c.field.hidden_dim_color = 48, &["colour MLP", "width", "got 48"]),
        (|c| c.field.appearance_embed_dim = 500, &["colour MLP", "appearance_embed_dim", "n_input"]),
        (|c| c.proposals[1].hidden_dim = 256, &["proposals[1]", "width"]),
        (|c| c.field.grid.max_resolution = 1 << 24, &["field.grid", "max_resolution", "at most 1048576"]),
        (|c| c.proposals[0].grid.max_resolution = u32::MAX, &["proposals[0].grid", "max_resolution"]),
    ];
    for (i, (edit, parts)) in cases.into_iter().enumerate() {
        let mut c = base.clone();
        edit(&mut c);
        let e = c.validate().expect_err("refused").to_string();
        for p in parts {
            assert!(e.contains(p), "case {i}: `{e}` does not name `{p}`");
        }
    }
    // The largest allowed grid and zero weight on some (not all) bands pass.
    let mut c = base.clone();
    c.field.grid.max_resolution = 1 << 20;
    c.loss.band_weights = Some(vec![1.0, 0.0, 1.0]);
    c.validate().expect("at the bounds");
}
