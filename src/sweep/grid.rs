//! Sweep grids (`configs/sweeps/*.yaml`): a base model, a training budget, the wall-clock points at which held-out
//! views are evaluated, and axes that map config keys to value lists. The cells are the cartesian product of the
//! axes (times the explicit `cells:` list, when there is one). Every cell is resolved into a model config before
//! anything trains, so a typo or an invalid combination is an error that names the key and the cell.
//!
//! ```yaml
//! name: widths
//! model: demo                      # built-in profile or YAML path (relative to this file)
//! budget: {time_s: 90}             # and/or steps: 2000
//! eval_at_s: [15, 30, 60, 90]
//! axes:
//!   field.hidden_dim: [16, 32, 64]           # dotted path into the model config
//!   proposals.*.samples: [24, 48]            # `*`: every list element; `proposals.0.samples`: one
//!   bands: [[0, 1, 2], [0, 1, 2, 3, 4, 5]]   # band subsets (indices into the dataset's bands)
//! cells:                           # optional: explicit cells (each combined with every point of `axes`)
//!   - {model: tiny}
//!   - {model: demo, trainer.rays_per_batch: 1024}
//! ```

use super::error::SweepError;
use crate::nerf::config::ModelConfig;
use serde::{Deserialize, Serialize};
use serde_yaml::{Mapping, Value};
use std::path::{Path, PathBuf};

/// How long each cell trains: wall-clock seconds of training, a step count, or both (whichever comes first).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    #[serde(default)]
    pub time_s: Option<f64>,
    #[serde(default)]
    pub steps: Option<u64>,
}

/// The grid file as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GridFile {
    name: String,
    #[serde(default)]
    description: Option<String>,
    /// What the report says about the limits of this sweep, verbatim.
    #[serde(default)]
    notes: Option<String>,
    model: String,
    budget: Budget,
    #[serde(default)]
    eval_at_s: Vec<f64>,
    #[serde(default = "default_eval_views")]
    eval_views: usize,
    #[serde(default = "default_eval_pixels")]
    eval_pixels: usize,
    #[serde(default)]
    axes: Mapping,
    #[serde(default)]
    cells: Option<Vec<Mapping>>,
}

fn default_eval_views() -> usize {
    3
}

fn default_eval_pixels() -> usize {
    2048
}

/// A parsed, checked grid.
#[derive(Clone, Debug, Serialize)]
pub struct Grid {
    pub name: String,
    pub description: Option<String>,
    pub notes: Option<String>,
    /// Base model: built-in name or a path (resolved against the grid file's folder).
    pub model: String,
    pub budget: Budget,
    /// Wall-clock seconds of training at which held-out views are evaluated, increasing; the end of the budget is
    /// always evaluated too.
    pub eval_at_s: Vec<f64>,
    /// Held-out views rendered whole at each point (evenly spread over the eval split).
    pub eval_views: usize,
    /// Held-out pixels of the trainer's own periodic check.
    pub eval_pixels: usize,
    /// Axis keys in file order.
    pub axes: Vec<(String, Vec<Value>)>,
    pub cells: Vec<Cell>,
    /// Where the grid came from (for messages).
    pub source: String,
}

/// One grid cell: its position and the value of every key it sets, in axis order.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Cell {
    pub index: usize,
    pub values: Vec<(String, Value)>,
}

/// A cell resolved into what the trainer needs.
#[derive(Clone, Debug)]
pub struct CellConfig {
    pub model: ModelConfig,
    /// Base model name or path of this cell.
    pub model_name: String,
    pub bands: Option<Vec<usize>>,
}

/// Keys that are not model-config paths.
pub const MODEL_KEY: &str = "model";
pub const BANDS_KEY: &str = "bands";

/// A value as the report and file names show it: `16`, `nerfacto`, `0+1+2`.
pub fn show_value(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Number(n) => n.to_string(),
        Value::Bool(b) => b.to_string(),
        Value::Null => "null".into(),
        Value::Sequence(s) => s.iter().map(show_value).collect::<Vec<_>>().join("+"),
        other => serde_yaml::to_string(other).unwrap_or_default().trim().replace('\n', " "),
    }
}

impl Cell {
    /// `field.hidden_dim=16, bands=0+1+2` (or `base` for a cell that changes nothing).
    pub fn describe(&self) -> String {
        if self.values.is_empty() {
            return "base".into();
        }
        self.values.iter().map(|(k, v)| format!("{k}={}", show_value(v))).collect::<Vec<_>>().join(", ")
    }

    /// The value the cell sets for `key`, if any.
    pub fn get(&self, key: &str) -> Option<&Value> {
        self.values.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    fn error(&self, msg: impl std::fmt::Display) -> SweepError {
        SweepError::Cell { index: self.index, describe: self.describe(), reason: msg.to_string() }
    }
}

impl Grid {
    /// Loads a grid file; errors name the file and the key or cell.
    pub fn load(path: &Path) -> Result<Grid, SweepError> {
        let text = std::fs::read_to_string(path).map_err(|e| SweepError::file(path, e))?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Grid::parse(&text, &dir, &path.display().to_string()).map_err(|e| SweepError::file(path, e))
    }

    /// Parses grid text; a relative `model:` path (base or axis value) is taken relative to `dir`.
    pub fn parse(text: &str, dir: &Path, source: &str) -> Result<Grid, SweepError> {
        let f: GridFile = serde_yaml::from_str(text).map_err(|e| SweepError::grid(e.to_string()))?;
        let b = &f.budget;
        if b.time_s.is_none() && b.steps.is_none() {
            return Err(SweepError::grid("budget: give `time_s`, `steps` or both"));
        }
        if let Some(t) = b.time_s.filter(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(SweepError::grid(format!("budget.time_s must be a positive number of seconds, got {t}")));
        }
        if b.steps == Some(0) {
            return Err(SweepError::grid("budget.steps must be > 0"));
        }
        for (i, t) in f.eval_at_s.iter().enumerate() {
            if !(t.is_finite() && *t > 0.0) {
                return Err(SweepError::grid(format!("eval_at_s[{i}]: must be a positive number of seconds, got {t}")));
            }
            if i > 0 && *t <= f.eval_at_s[i - 1] {
                return Err(SweepError::grid(format!(
                    "eval_at_s[{i}]: the points must increase ({} then {t})",
                    f.eval_at_s[i - 1]
                )));
            }
            if b.time_s.is_some_and(|tb| *t > tb) {
                return Err(SweepError::grid(format!(
                    "eval_at_s[{i}]: {t} s is past budget.time_s ({} s)",
                    b.time_s.unwrap_or(0.0)
                )));
            }
        }
        if f.eval_views == 0 {
            return Err(SweepError::grid("eval_views must be >= 1"));
        }
        let mut axes = Vec::new();
        for (k, v) in &f.axes {
            let key =
                k.as_str().ok_or_else(|| SweepError::grid(format!("axes: key {k:?} is not a string")))?.to_string();
            let values = match v {
                Value::Sequence(s) if !s.is_empty() => s.clone(),
                _ => return Err(SweepError::grid(format!("axes.{key}: expected a non-empty list of values"))),
            };
            axes.push((key, values));
        }
        let explicit: Vec<Vec<(String, Value)>> = match &f.cells {
            None => vec![vec![]],
            Some(list) if list.is_empty() => return Err(SweepError::grid("cells: the list is empty")),
            Some(list) => list
                .iter()
                .enumerate()
                .map(|(i, m)| {
                    m.iter()
                        .map(|(k, v)| {
                            let key = k
                                .as_str()
                                .ok_or_else(|| SweepError::grid(format!("cells[{i}]: key {k:?} is not a string")))?;
                            if axes.iter().any(|(a, _)| a == key) {
                                return Err(SweepError::grid(format!("cells[{i}]: key `{key}` is also an axis")));
                            }
                            Ok((key.to_string(), v.clone()))
                        })
                        .collect::<Result<Vec<_>, SweepError>>()
                })
                .collect::<Result<_, _>>()?,
        };
        // The grid's size before building it: a handful of long axes multiply into billions of cells.
        let per_base = axes.iter().try_fold(1usize, |n, (_, v)| n.checked_mul(v.len().max(1)));
        let total = per_base.and_then(|n| n.checked_mul(explicit.len()));
        if total.is_none_or(|n| n > MAX_CELLS) {
            let n = total.map_or("more than 2^64".to_string(), |n| n.to_string());
            return Err(SweepError::grid(format!("{n} cells: a sweep holds at most {MAX_CELLS}")));
        }
        let mut cells = Vec::new();
        for base in &explicit {
            for combo in cartesian(&axes) {
                let values: Vec<(String, Value)> = base.iter().cloned().chain(combo).collect();
                cells.push(Cell { index: cells.len(), values });
            }
        }
        let model = resolve_model_path(&f.model, dir);
        let mut grid = Grid {
            name: f.name,
            description: f.description,
            notes: f.notes,
            model,
            budget: f.budget,
            eval_at_s: f.eval_at_s,
            eval_views: f.eval_views,
            eval_pixels: f.eval_pixels,
            axes,
            cells,
            source: source.to_string(),
        };
        // Relative model paths in cells, then resolve every cell now so that errors come before any training.
        for c in &mut grid.cells {
            for (k, v) in &mut c.values {
                if k == MODEL_KEY {
                    if let Value::String(s) = v {
                        *s = resolve_model_path(s, dir);
                    }
                }
            }
        }
        for c in &grid.cells {
            grid.resolve(c)?;
            if let Some(d) = grid.cells[..c.index].iter().find(|d| d.describe() == c.describe()) {
                return Err(SweepError::grid(format!(
                    "cells {} and {} are the same configuration ({})",
                    d.index,
                    c.index,
                    c.describe()
                )));
            }
        }
        Ok(grid)
    }

    /// The model config and band subset of a cell: the base (or the cell's `model`) with every other key set,
    /// then checked as a model file is.
    pub fn resolve(&self, cell: &Cell) -> Result<CellConfig, SweepError> {
        let model_name = match cell.get(MODEL_KEY) {
            None => self.model.clone(),
            Some(Value::String(s)) => s.clone(),
            Some(v) => {
                return Err(cell.error(format!("key `model`: expected a model name or path, got {}", show_value(v))))
            }
        };
        let base = ModelConfig::resolve(&model_name).map_err(|e| cell.error(format!("key `model`: {e}")))?;
        let mut tree = serde_yaml::to_value(&base).map_err(|e| cell.error(e))?;
        let mut bands = None;
        for (key, value) in &cell.values {
            match key.as_str() {
                MODEL_KEY => {}
                BANDS_KEY => bands = Some(parse_bands(value).map_err(|e| cell.error(format!("key `bands`: {e}")))?),
                _ => set_path(&mut tree, key, value).map_err(|e| cell.error(format!("key `{key}`: {e}")))?,
            }
        }
        let mut model: ModelConfig =
            serde_yaml::from_value(tree).map_err(|e| cell.error(format!("the resulting model config: {e}")))?;
        // A smaller batch than the chunk size means one chunk of that batch (as `msnerf train --rays-per-batch`).
        if cell.get("trainer.rays_per_batch").is_some() && cell.get("trainer.rays_per_chunk").is_none() {
            model.trainer.set_rays_per_batch(model.trainer.rays_per_batch);
        }
        model.validate().map_err(|e| cell.error(format!("invalid model config: {e}")))?;
        Ok(CellConfig { model, model_name, bands })
    }
}

fn resolve_model_path(name: &str, dir: &Path) -> String {
    if ModelConfig::is_builtin(name) || Path::new(name).is_absolute() || dir.as_os_str().is_empty() {
        return name.to_string();
    }
    let p: PathBuf = dir.join(name);
    if p.is_file() {
        p.display().to_string()
    } else {
        name.to_string()
    }
}

/// Every combination of one value per axis, the first axis varying slowest.
/// Most cells a sweep grid may hold (each is a training run).
pub const MAX_CELLS: usize = 10_000;

fn cartesian(axes: &[(String, Vec<Value>)]) -> Vec<Vec<(String, Value)>> {
    let mut out = vec![vec![]];
    for (k, vals) in axes {
        out = out
            .into_iter()
            .flat_map(|prefix: Vec<(String, Value)>| {
                vals.iter().map(move |v| {
                    let mut p = prefix.clone();
                    p.push((k.clone(), v.clone()));
                    p
                })
            })
            .collect();
    }
    out
}

fn parse_bands(v: &Value) -> Result<Vec<usize>, SweepError> {
    let Value::Sequence(s) = v else {
        return Err(SweepError::grid(format!(
            "expected a list of band indices such as [0, 1, 2], got {}",
            show_value(v)
        )));
    };
    if s.is_empty() {
        return Err(SweepError::grid("the band list is empty"));
    }
    s.iter()
        .map(|x| {
            x.as_u64()
                .map(|i| i as usize)
                .ok_or_else(|| SweepError::grid(format!("`{}` is not a band index (0, 1, ...)", show_value(x))))
        })
        .collect()
}

/// Sets the value at a dotted path (`field.grid.log2_hashmap_size`, `proposals.0.samples`, `proposals.*.samples`).
/// Every segment must already exist: a model config serialises every key it knows, so a missing one is a typo.
pub fn set_path(tree: &mut Value, path: &str, value: &Value) -> Result<(), SweepError> {
    let segs: Vec<&str> = path.split('.').collect();
    if segs.iter().any(|s| s.is_empty()) {
        return Err(SweepError::grid("empty segment in the dotted path"));
    }
    set_rec(tree, &segs, value, "")
}

fn set_rec(node: &mut Value, segs: &[&str], value: &Value, at: &str) -> Result<(), SweepError> {
    let Some((&seg, rest)) = segs.split_first() else {
        if node.is_mapping() || node.is_sequence() {
            return Err(SweepError::grid(format!("`{at}` is a section, not a value: set one of its keys")));
        }
        *node = value.clone();
        return Ok(());
    };
    let here = if at.is_empty() { seg.to_string() } else { format!("{at}.{seg}") };
    match node {
        Value::Mapping(m) => {
            let known: Vec<String> = m.keys().filter_map(|k| k.as_str().map(str::to_string)).collect();
            let child = m.get_mut(seg).ok_or_else(|| {
                let where_ = if at.is_empty() { "the model config".to_string() } else { format!("`{at}`") };
                SweepError::grid(format!("no key `{seg}` in {where_} (known: {})", known.join(", ")))
            })?;
            set_rec(child, rest, value, &here)
        }
        Value::Sequence(s) => {
            if seg == "*" {
                for (i, item) in s.iter_mut().enumerate() {
                    set_rec(item, rest, value, &format!("{at}.{i}"))?;
                }
                return Ok(());
            }
            let n = s.len();
            let i: usize = seg.parse().map_err(|_| {
                SweepError::grid(format!("`{at}` is a list: use an index (0..{n}) or `*`, not `{seg}`"))
            })?;
            let item = s
                .get_mut(i)
                .ok_or_else(|| SweepError::grid(format!("`{at}` has {n} entries, index {i} is out of range")))?;
            set_rec(item, rest, value, &here)
        }
        _ => Err(SweepError::grid(format!("`{at}` is a value, it has no key `{seg}`"))),
    }
}
