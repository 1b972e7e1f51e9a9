//! Train/eval/test splits (dataset.md "Splits", first match wins): explicit `train_filenames` /
//! `val_filenames` / `test_filenames`; else per-frame `split`; else every 8th frame (index % 8 == 0, frames
//! sorted by file name) is held out for evaluation.

use serde::Serialize;

/// Which split a frame belongs to. `Unused` only happens with explicit file lists that do not name it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Split {
    Train,
    Eval,
    Test,
    Unused,
}

impl Split {
    /// Parses a per-frame `split` value (`val` and `validation` are accepted for `eval`).
    pub fn parse(s: &str) -> Option<Split> {
        match s.to_ascii_lowercase().as_str() {
            "train" => Some(Split::Train),
            "eval" | "val" | "validation" => Some(Split::Eval),
            "test" => Some(Split::Test),
            _ => None,
        }
    }
}

/// How the splits were decided.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SplitMethod {
    Filenames,
    PerFrame,
    Interval,
}

/// Explicit file lists from the top level of `transforms.json`.
#[derive(Debug, Clone, Default)]
pub struct SplitLists {
    pub train: Option<Vec<String>>,
    pub val: Option<Vec<String>>,
    pub test: Option<Vec<String>>,
}

impl SplitLists {
    pub fn any(&self) -> bool {
        self.train.is_some() || self.val.is_some() || self.test.is_some()
    }
}

/// `./a/b.png` and `a/b.png` compare equal.
pub fn normalize_name(s: &str) -> String {
    let mut s = s.replace('\\', "/");
    while let Some(rest) = s.strip_prefix("./") {
        s = rest.to_string();
    }
    s
}

fn listed(list: &Option<Vec<String>>, name: &str) -> bool {
    let n = normalize_name(name);
    let base = n.rsplit('/').next().unwrap_or(&n).to_string();
    list.as_ref().is_some_and(|l| {
        l.iter().any(|e| {
            let e = normalize_name(e);
            e == n || (!e.contains('/') && e == base)
        })
    })
}

/// Assigns splits to frames given in file-name order. `per_frame[i]` is frame i's own `split` key.
pub fn assign_splits(names: &[String], per_frame: &[Option<Split>], lists: &SplitLists) -> (Vec<Split>, SplitMethod) {
    if lists.any() {
        let s = names
            .iter()
            .map(|n| {
                if listed(&lists.train, n) {
                    Split::Train
                } else if listed(&lists.val, n) {
                    Split::Eval
                } else if listed(&lists.test, n) {
                    Split::Test
                } else {
                    Split::Unused
                }
            })
            .collect();
        return (s, SplitMethod::Filenames);
    }
    if per_frame.iter().any(|s| s.is_some()) {
        let s = per_frame.iter().map(|s| s.unwrap_or(Split::Train)).collect();
        return (s, SplitMethod::PerFrame);
    }
    let s = (0..names.len()).map(|i| if i % 8 == 0 { Split::Eval } else { Split::Train }).collect();
    (s, SplitMethod::Interval)
}
