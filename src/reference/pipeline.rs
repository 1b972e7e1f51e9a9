//! CPU reference of one whole nerfacto training step (f64), composed from the kernel twins: proposal sampling,
//! fields, compositing with the per-band MSE and distortion loss, the interlevel loss, and the backward pass into
//! every parameter slot, including the camera pose corrections when the model refines poses (the regulariser
//! averages over all of the model's cameras, as the GPU pipeline does by default). The GPU pipeline (`crate::nerf::pipeline`) is tested against it.

use super::{hashgrid, mlp, pose, render, sh};
use crate::nerf::model::Model;
use crate::nerf::schedule::anneal_at;

/// One ray of the batch, already generated (origin, unit direction; before any pose correction), with its camera,
/// targets and weight.
pub struct RefRay {
    pub origin: [f64; 3],
    pub dir: [f64; 3],
    pub camera: usize,
    pub target: Vec<f64>,
    pub weight: f64,
    /// With `loss.depth`: (target distance along the unit ray, standard deviation), normalised frame.
    pub depth: Option<(f64, f64)>,
}

#[derive(Debug, Default)]
pub struct RefStep {
    pub loss_rgb: f64,
    pub loss_distortion: f64,
    pub loss_interlevel: f64,
    pub loss_depth: f64,
    pub loss_pose: f64,
    /// dLoss/dparams over the whole store (same layout as the GPU arrays).
    pub grads: Vec<f64>,
}

/// What the interlevel backward needs from a proposal level's forward pass.
struct ProposalLevel {
    edges: Vec<f64>,
    encodings: Vec<Vec<f64>>,
    raw: Vec<f64>,
}

/// The training step's losses and gradients for `rays` at `step` (parameters `params`, the store's layout).
pub fn train_step(model: &Model, params: &[f64], rays: &[RefRay], step: u64, update_props: bool) -> RefStep {
    let cfg = &model.cfg;
    let s = &cfg.sampling;
    let bands = model.bands;
    let scale = cfg.field.average_init_density as f64;
    let seed = cfg.trainer.seed as u32;
    let anneal = anneal_at(s, step) as f64;
    let total_w: f64 = rays.iter().map(|r| r.weight).sum::<f64>().max(1.0);
    // The weighted count of observed (not NaN) targets: total_w * B when every band is observed.
    let observed: f64 = rays.iter().map(|r| r.weight * r.target.iter().filter(|v| !v.is_nan()).count() as f64).sum();
    let rgb_norm = 1.0 / observed.max(bands as f64);
    let dist_norm = cfg.loss.distortion_mult as f64 / total_w;
    let inter_norm = cfg.loss.interlevel_mult as f64 / (rays.len() * s.num_nerf_samples) as f64;
    let band_w: Vec<f64> = cfg.band_weights(bands).expect("validated").iter().map(|&v| v as f64).collect();
    let chosen = cfg.rendering.background_at(step, true);
    let background = match chosen {
        crate::nerf::config::Background::LastSample => render::Background::LastSample,
        crate::nerf::config::Background::Black => render::Background::Constant(0.0),
        crate::nerf::config::Background::White => render::Background::Constant(1.0),
        crate::nerf::config::Background::Random => render::Background::Constant(f64::NAN), // per ray, below
    };
    let mut out = RefStep { grads: vec![0.0; params.len()], ..Default::default() };
    let slice = |offset: usize, len: usize| offset..offset + len;

    let pose_off = model.slots.pose.as_ref().map(|sl| sl.offset);
    for (gi, ray) in rays.iter().enumerate() {
        // Pose correction (training): origin + t, direction rotated by exp(w).
        let (origin, dir) = match pose_off {
            Some(o) => pose::apply(&params[o + 6 * ray.camera..o + 6 * ray.camera + 6], ray.origin, ray.dir),
            None => (ray.origin, ray.dir),
        };
        let geom =
            render::RayGeom { origin, dir, near: s.near as f64, far: s.far as f64, contraction: s.scene_contraction };
        let jitter = |level: u32| render::ray_uniform(seed, step as u32, gi as u32, level) as f64;
        // Proposal levels: forward, keeping what the interlevel backward needs.
        let mut levels: Vec<ProposalLevel> = Vec::new();
        let mut prev: Option<(Vec<f64>, Vec<f64>)> = None; // (edges, weights)
        for (p, (field, pc)) in model.proposals.iter().zip(&cfg.proposals).enumerate() {
            let edges = match &prev {
                None => render::initial_edges(pc.samples, jitter(0), s.single_jitter),
                Some((e, w)) => render::pdf_resample(e, w, pc.samples, anneal, jitter(p as u32), s.single_jitter),
            };
            let grid = &params[slice(field.grid_offset, pc.grid.n_params())];
            let w_mlp = &params[slice(field.mlp_offset, field.mlp.config.n_params())];
            let levels_tab = pc.grid.levels();
            let in_pad = field.mlp.config.in_pad();
            let mut encs = Vec::new();
            let mut raw = Vec::new();
            for pos in geom.positions(&edges) {
                let mut enc = hashgrid::forward(&levels_tab, pc.grid.features_per_level as usize, grid, pos);
                enc.resize(in_pad, 1.0);
                raw.push(mlp::forward(&field.mlp.config, w_mlp, &enc).1[0]);
                encs.push(enc);
            }
            let w = render::weights(&geom, &edges, &raw, scale);
            prev = Some((edges.clone(), w));
            levels.push(ProposalLevel { edges, encodings: encs, raw });
        }
        // NeRF level.
        let n = s.num_nerf_samples;
        let level = model.proposals.len() as u32;
        let edges = match &prev {
            None => render::initial_edges(n, jitter(0), s.single_jitter),
            Some((e, w)) => render::pdf_resample(e, w, n, anneal, jitter(level), s.single_jitter),
        };
        let f = &model.field;
        let fg = &cfg.field.grid;
        let grid_levels = fg.levels();
        // field.coarse_to_fine: the held-back levels' weights.
        let c2f = hashgrid::level_weights(grid_levels.len(), cfg.field.active_levels_at(step) as f64);
        let grid = &params[slice(f.grid_offset, fg.n_params())];
        let fm = &f.mlp.config;
        let w_density = &params[slice(f.mlp_offset, fm.n_params())];
        let cm = &model.colour.config;
        let w_colour = &params[slice(model.slots.colour_mlp.offset, cm.n_params())];
        let (geo_dim, app_dim) = (cfg.field.geo_feat_dim, cfg.field.appearance_embed_dim);
        // field.direction_sh_degree: the SH values past its square are zero columns.
        let sh_count = cfg.field.sh_count();
        let mut shv = sh::encode(dir);
        shv[sh_count.min(sh::SH_DIM)..].fill(0.0);
        let app: Vec<f64> = if app_dim > 0 {
            let o = model.slots.appearance.as_ref().expect("appearance slot").offset + ray.camera * app_dim;
            params[o..o + app_dim].to_vec()
        } else {
            vec![]
        };
        let positions = geom.positions(&edges);
        let mut encs = Vec::new();
        let mut raw = Vec::new();
        let mut cin = Vec::new();
        let mut colours = Vec::new();
        for pos in &positions {
            let mut enc = hashgrid::forward_weighted(&grid_levels, fg.features_per_level as usize, grid, *pos, &c2f);
            enc.resize(fm.in_pad(), 0.0);
            let dens = mlp::forward(fm, w_density, &enc).1;
            raw.push(dens[0]);
            let mut row: Vec<f64> = shv.to_vec();
            row.extend_from_slice(&dens[1..1 + geo_dim]);
            row.extend_from_slice(&app);
            row.resize(cm.in_pad(), 1.0);
            colours.extend(mlp::forward(cm, w_colour, &row).1);
            encs.push(enc);
            cin.push(row);
        }
        let comp = render::composite(&render::CompositeIn {
            geom,
            edges: &edges,
            raw: &raw,
            colours: &colours,
            target: &ray.target,
            ray_weight: ray.weight,
            band_weights: &band_w,
            density_scale: scale,
            background: if matches!(chosen, crate::nerf::config::Background::Random) {
                render::Background::Random { seed, step: step as u32, ray: gi as u32 }
            } else {
                background
            },
            rgb_norm,
            dist_norm,
            grad_scaling: cfg.loss.gradient_scaling,
            depth: cfg.loss.depth.zip(ray.depth).map(|(d, (distance, sigma))| render::DepthTarget {
                loss: d.loss,
                distance,
                sigma,
                norm: d.mult as f64 / total_w,
            }),
        });
        out.loss_rgb += comp.loss_rgb;
        out.loss_distortion += comp.loss_dist;
        out.loss_depth += comp.loss_depth;
        // Backward through the colour MLP, then the density MLP and the hash grid.
        let (co, fo, go) = (model.slots.colour_mlp.offset, f.mlp_offset, f.grid_offset);
        let mut dpos = vec![0.0; 3 * n];
        let mut dsh = [0.0; sh::SH_DIM];
        for k in 0..n {
            let dy_c = &comp.d_colour[k * bands..(k + 1) * bands];
            let dx = mlp::backward(cm, w_colour, &cin[k], dy_c, &mut out.grads[co..co + cm.n_params()]);
            if app_dim > 0 {
                let o = model.slots.appearance.as_ref().expect("appearance slot").offset + ray.camera * app_dim;
                for a in 0..app_dim {
                    out.grads[o + a] += dx[sh::SH_DIM + geo_dim + a];
                }
            }
            let mut dy_d = vec![comp.d_raw[k]];
            dy_d.extend_from_slice(&dx[sh::SH_DIM..sh::SH_DIM + geo_dim]);
            let dx_enc = mlp::backward(fm, w_density, &encs[k], &dy_d, &mut out.grads[fo..fo + fm.n_params()]);
            if pose_off.is_some() {
                let fpl = fg.features_per_level as usize;
                let gh = hashgrid::backward_input_weighted(&grid_levels, fpl, grid, positions[k], &dx_enc, &c2f);
                dpos[3 * k..3 * k + 3].copy_from_slice(&gh);
                for (a, v) in dsh.iter_mut().zip(&dx[..sh_count.min(sh::SH_DIM)]) {
                    *a += v;
                }
            }
            hashgrid::backward_params_weighted(
                &grid_levels,
                fg.features_per_level as usize,
                positions[k],
                &dx_enc,
                &mut out.grads[go..go + fg.n_params()],
                &c2f,
            );
        }
        let near_far = (s.near as f64, s.far as f64, s.scene_contraction);
        let (mut g_o, mut g_d) = pose::ray_grad(origin, dir, &edges, near_far, &dpos, Some(&dsh));
        if update_props {
            for ((field, pc), lv) in model.proposals.iter().zip(&cfg.proposals).zip(&levels) {
                let ld = proposal_backward(
                    model,
                    params,
                    &geom,
                    (field, pc),
                    lv,
                    (&edges, &comp.weights, inter_norm),
                    pose_off.is_some(),
                    &mut out,
                );
                if pose_off.is_some() {
                    let (po, pd) = pose::ray_grad(origin, dir, &lv.edges, near_far, &ld, None);
                    g_o = [0, 1, 2].map(|i| g_o[i] + po[i]);
                    g_d = [0, 1, 2].map(|i| g_d[i] + pd[i]);
                }
            }
        }
        if let Some(o) = pose_off {
            let p = &params[o + 6 * ray.camera..o + 6 * ray.camera + 6];
            let g = pose::camera_grad([p[3], p[4], p[5]], ray.dir, g_o, g_d);
            for (i, v) in g.iter().enumerate() {
                out.grads[o + 6 * ray.camera + i] += v;
            }
        }
    }
    if let Some(o) = pose_off {
        let co = &cfg.camera_optimizer;
        let poses = &params[o..o + 6 * model.n_cameras];
        let (losses, g) =
            pose::regularizer(poses, model.n_cameras, co.trans_l2_penalty as f64, co.rot_l2_penalty as f64);
        out.loss_pose = losses.iter().sum();
        for (i, v) in g.iter().enumerate() {
            out.grads[o + i] += v;
        }
    }
    out
}

/// Interlevel loss of one proposal level (added to `out`) and its backward into the proposal's MLP and grid; returns
/// the hash-input gradient of the level's samples (3 per sample) when `with_dpos` (pose refinement), else nothing.
#[allow(clippy::too_many_arguments)]
fn proposal_backward(
    model: &Model,
    params: &[f64],
    geom: &render::RayGeom<f64>,
    (field, pc): (&crate::nerf::model::DensityField, &crate::nerf::config::ProposalConfig),
    lv: &ProposalLevel,
    (nerf_edges, nerf_weights, inter_norm): (&[f64], &[f64], f64),
    with_dpos: bool,
    out: &mut RefStep,
) -> Vec<f64> {
    let scale = model.cfg.field.average_init_density as f64;
    let (pedges, pencs, praw) = (&lv.edges, &lv.encodings, &lv.raw);
    let (loss, d_raw) = render::interlevel(geom, nerf_edges, nerf_weights, pedges, praw, scale, inter_norm);
    out.loss_interlevel += loss;
    let (mo, go) = (field.mlp_offset, field.grid_offset);
    let w_mlp = &params[mo..mo + field.mlp.config.n_params()];
    let grid = &params[go..go + pc.grid.n_params()];
    let plevels = pc.grid.levels();
    let fpl = pc.grid.features_per_level as usize;
    let ppos = geom.positions(pedges);
    let mut dpos = Vec::with_capacity(3 * praw.len());
    for k in 0..praw.len() {
        let mlp_grads = &mut out.grads[mo..mo + field.mlp.config.n_params()];
        let dx = mlp::backward(&field.mlp.config, w_mlp, &pencs[k], &[d_raw[k]], mlp_grads);
        hashgrid::backward_params(&plevels, fpl, ppos[k], &dx, &mut out.grads[go..go + pc.grid.n_params()]);
        if with_dpos {
            dpos.extend(hashgrid::backward_input(&plevels, fpl, grid, ppos[k], &dx));
        }
    }
    dpos
}
