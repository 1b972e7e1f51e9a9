//! Density-field normals (`msnerf::nerf::normals`) on lavapipe: the GPU chain (hash grid -> density MLP -> MLP
//! backward -> `hashgrid_bwd_input` -> contraction Jacobian) against the CPU twins chained the same way
//! (`reference::{hashgrid, mlp, render, pose}`) and against central finite differences of the f64 twin's density.

use crate::common;
use common::{gpu, rng};
use msnerf::nerf::config::ModelConfig;
use msnerf::nerf::model::Model;
use msnerf::nerf::normals::{density_gradients, normal_from_gradient};
use msnerf::nn::mlp::MlpConfig;
use msnerf::reference::pose::hash_input_grad;
use msnerf::reference::render::hash_input;
use msnerf::reference::{hashgrid, mlp};
use num_traits::Float;
use rand::Rng;

/// The field's parameters on the CPU.
struct Field {
    levels: Vec<msnerf::nn::hashgrid::HashLevel>,
    features: usize,
    grid: Vec<f64>,
    mlp_cfg: MlpConfig,
    mlp: Vec<f64>,
}

impl Field {
    fn encode<T: Float>(&self, x: [T; 3]) -> Vec<T> {
        let g: Vec<T> = self.grid.iter().map(|&v| T::from(v as f32).expect("f32")).collect();
        let mut e = hashgrid::forward(&self.levels, self.features, &g, hash_input(x, true).0);
        e.resize(self.mlp_cfg.in_pad(), T::zero()); // the field pads its MLP input with zeros
        e
    }

    fn weights<T: Float>(&self) -> Vec<T> {
        self.mlp.iter().map(|&v| T::from(v as f32).expect("f32")).collect()
    }

    /// Raw density at x (the f64 twin, for finite differences).
    fn raw_density(&self, x: [f64; 3]) -> f64 {
        mlp::forward(&self.mlp_cfg, &self.weights::<f64>(), &self.encode(x)).1[0]
    }

    /// d(raw density)/dx through the twins, in T.
    fn gradient<T: Float>(&self, x: [T; 3]) -> [T; 3] {
        let enc = self.encode(x);
        let mut dy = vec![T::zero(); self.mlp_cfg.n_output];
        dy[0] = T::one();
        let mut wg = vec![T::zero(); self.mlp.len()];
        let dx = mlp::backward(&self.mlp_cfg, &self.weights::<T>(), &enc, &dy, &mut wg);
        let g: Vec<T> = self.grid.iter().map(|&v| T::from(v as f32).expect("f32")).collect();
        let lf = self.levels.len() * self.features;
        let dh = hashgrid::backward_input(&self.levels, self.features, &g, hash_input(x, true).0, &dx[..lf]);
        hash_input_grad(x, dh, true)
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

#[test]
fn density_normals_match_the_cpu_chain_and_finite_differences() {
    let g = gpu();
    let cfg = ModelConfig::resolve("tiny").expect("tiny");
    let model = Model::new(&g, &cfg, 6, 4).expect("model");
    // A random field: hash features in [-0.5, 0.5] (the initialisation's 1e-4 would make gradients vanish).
    let mut r = rng(7);
    let store = &model.store;
    let grid_slot = store.slot("field.grid").expect("grid").clone();
    let grid: Vec<f32> = (0..grid_slot.len).map(|_| r.random_range(-0.5f32..0.5)).collect();
    store.upload_slot(store.params(), &grid_slot, &grid).expect("upload grid");
    let mlp_slot = store.slot("field.mlp").expect("mlp").clone();
    let weights = store.download_slot(store.params(), &mlp_slot).expect("mlp weights");
    let field = Field {
        levels: cfg.field.grid.levels(),
        features: cfg.field.grid.features_per_level as usize,
        grid: grid.iter().map(|&v| v as f64).collect(),
        mlp_cfg: model.field.mlp.config.clone(),
        mlp: weights.iter().map(|&v| v as f64).collect(),
    };
    // Points inside the unit cube and in the contracted region, away from the cube's faces.
    let mut points: Vec<[f64; 3]> = (0..150).map(|_| [0, 1, 2].map(|_| r.random_range(-0.95..0.95))).collect();
    points.extend((0..50).map(|_| {
        let p = [0, 1, 2].map(|_| r.random_range(-3.0..3.0));
        let m = p.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if m < 1.1 {
            p.map(|v| v * 1.5 / m)
        } else {
            p
        }
    }));
    let got = density_gradients(&g, &model, &points).expect("GPU gradients");
    assert_eq!(got.len(), points.len());
    // The store's gradients are left zero (the MLP backward's weight gradients are scratch).
    let grads = store.download_slot(store.grads(), &mlp_slot).expect("grads");
    assert!(grads.iter().all(|&v| v == 0.0), "weight gradients are zeroed after the normals pass");

    let (mut twin_bad, mut fd_bad) = (Vec::new(), Vec::new());
    let (mut twin_err, mut fd_err) = (Vec::new(), Vec::new());
    for (i, (&x, &gg)) in points.iter().zip(&got).enumerate() {
        // GPU against the f32 twin chain: fp32 rounding differs only in summation order.
        let xf = x.map(|v| v as f32);
        let tw = field.gradient(xf).map(|v| v as f64);
        let scale = norm(tw);
        assert!(scale > 1e-6, "point {i}: the random field has a gradient");
        twin_err.push((0..3).map(|k| (gg[k] - tw[k]).abs() / scale).fold(0.0, f64::max));
        if (0..3).any(|k| (gg[k] - tw[k]).abs() > 1e-5 + 1e-3 * scale) {
            twin_bad.push((i, gg, tw));
        }
        // The f64 twin's analytic gradient against central differences of its density (h = 1e-6 in the
        // normalised frame: ~1e-3 of the finest cell, so a difference rarely straddles a cell or ReLU boundary).
        let xd = xf.map(f64::from);
        let an = field.gradient(xd);
        let h = 1e-6;
        let fd = [0, 1, 2].map(|k| {
            let (mut a, mut b) = (xd, xd);
            a[k] += h;
            b[k] -= h;
            (field.raw_density(a) - field.raw_density(b)) / (2.0 * h)
        });
        fd_err.push((0..3).map(|k| (an[k] - fd[k]).abs() / norm(an)).fold(0.0, f64::max));
        if (0..3).any(|k| (an[k] - fd[k]).abs() > 1e-4 * norm(an).max(1e-3)) {
            fd_bad.push((i, an, fd));
        }
        // The normal: unit length, opposite the gradient, turned toward the viewer.
        let view = [0.3, -0.2, -0.93];
        let n = normal_from_gradient(gg, view).expect("non-zero gradient");
        assert!((norm(n) - 1.0).abs() < 1e-12);
        assert!(n[0] * view[0] + n[1] * view[1] + n[2] * view[2] <= 0.0);
        let along = -(n[0] * gg[0] + n[1] * gg[1] + n[2] * gg[2]) / norm(gg);
        assert!((along.abs() - 1.0).abs() < 1e-9, "the normal is parallel to the gradient");
    }
    let pct = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * q) as usize]
    };
    eprintln!(
        "relative error vs twin: median {:.1e}, 99th {:.1e}; twin vs finite differences: median {:.1e}, 99th {:.1e}",
        pct(&mut twin_err, 0.5),
        pct(&mut twin_err, 0.99),
        pct(&mut fd_err, 0.5),
        pct(&mut fd_err, 0.99)
    );
    // tcnn's rule for hash-grid gradients: the worst 1 % may be cell-boundary outliers.
    assert!(
        twin_bad.len() <= points.len() / 100,
        "{} of {} points differ from the twin: {:?}",
        twin_bad.len(),
        points.len(),
        &twin_bad[..twin_bad.len().min(3)]
    );
    assert!(
        fd_bad.len() <= points.len() / 100,
        "{} of {} points differ from finite differences: {:?}",
        fd_bad.len(),
        points.len(),
        &fd_bad[..fd_bad.len().min(3)]
    );
    assert_eq!(normal_from_gradient([0.0; 3], [0.0, 0.0, -1.0]), None, "a vanishing gradient has no normal");
}
