//! Shared by the pose-import tests: the simulated cameras as ground truth, file stems, dataset copies.

#![allow(dead_code)]

use std::path::Path;

use serde_json::Value;

pub struct Truth {
    pub names: Vec<String>,
    pub c2w: Vec<[[f64; 4]; 4]>,
    pub cam: [f64; 4],
    pub size: (u64, u64),
}

pub fn truth(data: &Path) -> Truth {
    let t: Value = serde_json::from_str(&std::fs::read_to_string(data.join("transforms.json")).unwrap()).unwrap();
    let frames = t["frames"].as_array().unwrap();
    let m =
        |v: &Value| -> [[f64; 4]; 4] { std::array::from_fn(|i| std::array::from_fn(|j| v[i][j].as_f64().unwrap())) };
    Truth {
        names: frames.iter().map(|f| f["file_path"].as_str().unwrap().to_string()).collect(),
        c2w: frames.iter().map(|f| m(&f["transform_matrix"])).collect(),
        cam: ["fl_x", "fl_y", "cx", "cy"].map(|k| t[k].as_f64().unwrap()),
        size: (t["w"].as_u64().unwrap(), t["h"].as_u64().unwrap()),
    }
}

/// The file name without folders and extension.
pub fn stem(p: &str) -> &str {
    let b = p.rsplit('/').next().unwrap();
    b.rsplit_once('.').map(|x| x.0).unwrap_or(b)
}

/// Copies a dataset folder (recursively).
pub fn copy_dataset(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        let to = dst.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dataset(&p, &to);
        } else {
            std::fs::copy(&p, &to).unwrap();
        }
    }
}
