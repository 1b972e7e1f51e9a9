//! Sweep grids: the cartesian product of the axes (and of explicit cells), applying a cell's values to the model
//! config, and errors that name the key and the cell for typos, bad values and invalid combinations.

use crate::common;
use msnerf::sweep::grid::set_path;
use msnerf::sweep::Grid;
use serde_yaml::Value;
use std::path::Path;

fn parse(text: &str) -> Result<Grid, String> {
    Grid::parse(text, Path::new(""), "test.yaml").map_err(|e| e.to_string())
}

const HEAD: &str = "name: t\nmodel: tiny\nbudget: {time_s: 10}\neval_at_s: [5]\n";

#[test]
fn cells_are_the_cartesian_product_of_the_axes_first_axis_slowest() {
    let g =
        parse(&format!("{HEAD}axes:\n  field.hidden_dim: [16, 32]\n  field.grid.log2_hashmap_size: [14, 15, 16]\n"))
            .expect("grid");
    assert_eq!(g.cells.len(), 6);
    let shown: Vec<String> = g.cells.iter().map(|c| c.describe()).collect();
    assert_eq!(shown[0], "field.hidden_dim=16, field.grid.log2_hashmap_size=14");
    assert_eq!(shown[2], "field.hidden_dim=16, field.grid.log2_hashmap_size=16");
    assert_eq!(shown[3], "field.hidden_dim=32, field.grid.log2_hashmap_size=14");
    assert_eq!(shown[5], "field.hidden_dim=32, field.grid.log2_hashmap_size=16");
    for (i, c) in g.cells.iter().enumerate() {
        assert_eq!(c.index, i);
        let m = g.resolve(c).expect("resolves").model;
        assert_eq!(m.field.hidden_dim as u64, c.get("field.hidden_dim").and_then(Value::as_u64).expect("set"));
        assert_eq!(m.field.grid.log2_hashmap_size as u64, c.values[1].1.as_u64().expect("number"));
        // Everything the cell does not set keeps the base profile's value.
        assert_eq!(m.field.hidden_dim_color, 32);
        assert_eq!(m.name, "tiny");
    }
}

#[test]
fn explicit_cells_combine_with_the_axes_and_can_switch_model_and_bands() {
    let g = parse(&format!(
        "{HEAD}axes:\n  trainer.rays_per_batch: [128, 256]\ncells:\n  - {{}}\n  - {{model: demo}}\n  - {{bands: [0, 1, 2]}}\n"
    ))
    .expect("grid");
    assert_eq!(g.cells.len(), 6);
    assert_eq!(g.cells[0].describe(), "trainer.rays_per_batch=128");
    assert_eq!(g.cells[2].describe(), "model=demo, trainer.rays_per_batch=128");
    let demo = g.resolve(&g.cells[3]).expect("demo cell");
    assert_eq!(demo.model.name, "demo");
    assert_eq!(demo.model.trainer.rays_per_batch, 256);
    // A batch smaller than the chunk becomes one chunk, as `msnerf train --rays-per-batch` does.
    assert_eq!(demo.model.trainer.rays_per_chunk, 256);
    let rgb = g.resolve(&g.cells[4]).expect("bands cell");
    assert_eq!(rgb.bands, Some(vec![0, 1, 2]));
    assert_eq!(rgb.model.name, "tiny");
    assert_eq!(g.resolve(&g.cells[0]).expect("base").bands, None);
}

#[test]
fn no_axes_and_no_cells_is_one_base_cell() {
    let g = parse(HEAD).expect("grid");
    assert_eq!(g.cells.len(), 1);
    assert_eq!(g.cells[0].describe(), "base");
    assert_eq!(
        g.resolve(&g.cells[0]).expect("base").model,
        msnerf::nerf::config::ModelConfig::resolve("tiny").unwrap()
    );
}

#[test]
fn wildcards_and_list_indices_reach_every_proposal_or_one() {
    let g = parse(&format!("{HEAD}axes:\n  proposals.*.samples: [8]\n  proposals.1.hidden_dim: [32]\n")).expect("grid");
    let m = g.resolve(&g.cells[0]).expect("resolves").model;
    assert_eq!(m.proposals.iter().map(|p| p.samples).collect::<Vec<_>>(), vec![8, 8]);
    assert_eq!(m.proposals[0].hidden_dim, 16);
    assert_eq!(m.proposals[1].hidden_dim, 32);
}

fn err_of(text: &str) -> String {
    parse(text).expect_err("the grid must be rejected")
}

#[test]
fn an_unknown_key_names_the_key_the_cell_and_what_is_known() {
    let e = err_of(&format!("{HEAD}axes:\n  field.hidden_dim: [16]\n  field.hiden_dim_color: [8, 16]\n"));
    assert!(e.contains("cell 0"), "{e}");
    assert!(e.contains("field.hiden_dim_color"), "{e}");
    assert!(e.contains("no key `hiden_dim_color` in `field`"), "{e}");
    assert!(e.contains("hidden_dim_color"), "lists the known keys: {e}");
    let e = err_of(&format!("{HEAD}axes:\n  feld.hidden_dim: [16]\n"));
    assert!(e.contains("no key `feld` in the model config"), "{e}");
}

#[test]
fn bad_values_and_invalid_combinations_name_the_cell() {
    // A string where a width goes: the cell and its settings are named.
    let e = err_of(&format!("{HEAD}axes:\n  field.hidden_dim: [16, wide]\n"));
    assert!(e.contains("cell 1 (field.hidden_dim=wide)"), "{e}");
    // Parses, but the model config rejects it (tcnn needs a hidden layer).
    let e = err_of(&format!("{HEAD}axes:\n  field.num_layers: [2, 1]\n"));
    assert!(e.contains("cell 1 (field.num_layers=1)") && e.contains("num_layers"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  sampling.num_nerf_samples: [0]\n"));
    assert!(e.contains("cell 0") && e.contains("num_nerf_samples must be > 0"), "{e}");
    // Sections are not values; list indices must exist.
    let e = err_of(&format!("{HEAD}axes:\n  field.grid: [1]\n"));
    assert!(e.contains("`field.grid` is a section"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  proposals.5.samples: [1]\n"));
    assert!(e.contains("index 5 is out of range"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  proposals.first.samples: [1]\n"));
    assert!(e.contains("use an index"), "{e}");
    // Special keys.
    let e = err_of(&format!("{HEAD}axes:\n  model: [tiny, no-such-profile]\n"));
    assert!(e.contains("cell 1") && e.contains("key `model`") && e.contains("no-such-profile"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  bands: [[0, 1], [red]]\n"));
    assert!(e.contains("cell 1") && e.contains("key `bands`") && e.contains("not a band index"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  bands: [[]]\n"));
    assert!(e.contains("key `bands`") && e.contains("empty"), "{e}");
}

#[test]
fn grid_level_mistakes_are_errors_naming_the_key() {
    let e = err_of("name: t\nmodel: tiny\nbudget: {}\n");
    assert!(e.contains("budget"), "{e}");
    let e = err_of("name: t\nmodel: tiny\nbudget: {time_s: 10}\neval_at_s: [5, 20]\n");
    assert!(e.contains("eval_at_s[1]") && e.contains("past budget.time_s"), "{e}");
    let e = err_of("name: t\nmodel: tiny\nbudget: {time_s: 10}\neval_at_s: [5, 3]\n");
    assert!(e.contains("eval_at_s[1]") && e.contains("increase"), "{e}");
    let e = err_of("name: t\nmodel: tiny\nbudget: {time_s: 10}\naxis:\n  field.hidden_dim: [16]\n");
    assert!(e.contains("unknown field `axis`"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  field.hidden_dim: 16\n"));
    assert!(e.contains("axes.field.hidden_dim") && e.contains("list"), "{e}");
    let e = err_of(&format!("{HEAD}axes:\n  field.hidden_dim: [16]\ncells:\n  - {{field.hidden_dim: 32}}\n"));
    assert!(e.contains("cells[0]") && e.contains("also an axis"), "{e}");
    let e = err_of(&format!("{HEAD}cells:\n  - {{field.hidden_dim: 16}}\n  - {{}}\n  - {{field.hidden_dim: 16}}\n"));
    assert!(e.contains("cells 0 and 2 are the same configuration"), "{e}");
    let e = err_of("name: t\nmodel: tiny\nbudget: {steps: 0}\n");
    assert!(e.contains("budget.steps"), "{e}");
    // Four axes of 100 values: 10^8 cells, refused before any is built (an audit's 4e9-cell grid ran out of memory).
    let axis = |k: &str| format!("  {k}: [{}]\n", (1..=100).map(|v| v.to_string()).collect::<Vec<_>>().join(", "));
    let axes: String = ["trainer.seed", "sampling.near", "sampling.far", "loss.interlevel_mult"].map(axis).concat();
    let e = err_of(&format!("{HEAD}axes:\n{axes}"));
    assert!(e.contains("100000000 cells") && e.contains("at most 10000"), "{e}");
}

#[test]
fn grid_files_resolve_model_paths_next_to_them_and_errors_name_the_file() {
    let dir = common::TempDir::new("sweep_grid");
    let model = msnerf::nerf::config::ModelConfig::resolve("tiny").unwrap();
    let mut mine = model.clone();
    mine.name = "mine".into();
    std::fs::write(dir.path().join("mine.yaml"), serde_yaml::to_string(&mine).unwrap()).unwrap();
    let grid = dir.path().join("g.yaml");
    std::fs::write(&grid, "name: t\nmodel: mine.yaml\nbudget: {steps: 3}\naxes:\n  model: [tiny, mine.yaml]\n")
        .unwrap();
    let g = Grid::load(&grid).expect("grid with relative model paths");
    assert_eq!(g.resolve(&g.cells[0]).unwrap().model.name, "tiny");
    assert_eq!(g.resolve(&g.cells[1]).unwrap().model.name, "mine");
    std::fs::write(&grid, "name: t\nmodel: tiny\nbudget: {steps: 3}\naxes:\n  field.nope: [1]\n").unwrap();
    let e = Grid::load(&grid).expect_err("typo").to_string();
    assert!(e.starts_with(&grid.display().to_string()) && e.contains("field.nope"), "{e}");
}

#[test]
fn the_shipped_grids_parse() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/sweeps");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).expect("configs/sweeps") {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "yaml") {
            let g = Grid::load(&p).unwrap_or_else(|e| panic!("{e}"));
            assert!(!g.cells.is_empty());
            n += 1;
        }
    }
    assert!(n >= 4, "configs/sweeps holds the ablation grids and the report grid");
    let t1 = Grid::load(&dir.join("ablation-table1.yaml")).unwrap();
    let names: Vec<String> = t1.cells.iter().map(|c| t1.resolve(c).unwrap().model.name).collect();
    assert_eq!(names, ["nerfacto", "multispectral-nerf"]);
    let bands = Grid::load(&dir.join("ablation-bands.yaml")).unwrap();
    let b: Vec<usize> = bands.cells.iter().map(|c| bands.resolve(c).unwrap().bands.unwrap().len()).collect();
    assert_eq!(b, [3, 6]);
}

#[test]
fn set_path_edits_only_the_named_value() {
    let mut v: Value = serde_yaml::from_str("a: {b: 1, c: [ {d: 1}, {d: 2} ]}").unwrap();
    set_path(&mut v, "a.b", &Value::from(5)).unwrap();
    set_path(&mut v, "a.c.*.d", &Value::from(7)).unwrap();
    assert_eq!(v, serde_yaml::from_str::<Value>("a: {b: 5, c: [ {d: 7}, {d: 7} ]}").unwrap());
    assert!(set_path(&mut v, "a..b", &Value::from(1)).unwrap_err().to_string().contains("empty segment"));
    assert!(set_path(&mut v, "a.b.x", &Value::from(1)).unwrap_err().to_string().contains("is a value"));
}
