//! Adam (`adam_step` over a `ParamStore`): hand-computed step sequences, the kernel against its CPU twin on
//! ~100k parameters in several groups and chunks (one group skipped in some steps), epsilon 1e-15 with zero or
//! vanishing gradients, frozen (lr 0) groups, and the ExponentialDecay schedule.
//! Tolerance: fp32 |a-b| <= 1e-5 + 1e-4|b|.

use crate::common;
use common::{assert_all_close_f32, close_f32, gpu, rng};
use msnerf::gpu::Context;
use msnerf::nn::adam::{self, AdamHyper};
use msnerf::nn::params::{MatrixShape, ParamGroup, ParamStore, ParamStoreDesc, SlotDesc, SlotKind};
use msnerf::reference::adam::{adam_step, AdamScalars};
use rand::Rng;

fn store(g: &Context, groups: Vec<ParamGroup>, slots: Vec<SlotDesc>, chunk_shift: Option<u32>) -> ParamStore {
    ParamStore::new(g, &ParamStoreDesc { name: "test", groups, slots, seed: 5, chunk_shift }).expect("param store")
}

fn set(s: &ParamStore, slot: &str, grads: bool, data: &[f32]) {
    let sl = s.slot(slot).expect("slot").clone();
    let arr = if grads { s.grads() } else { s.params() };
    s.upload_slot(arr, &sl, data).expect("upload slot");
}

fn get(s: &ParamStore, slot: &str, which: &str) -> Vec<f32> {
    let sl = s.slot(slot).expect("slot").clone();
    let arr = match which {
        "p" => s.params(),
        "g" => s.grads(),
        "m" => s.m(),
        _ => s.v(),
    };
    s.download_slot(arr, &sl).expect("download slot")
}

fn step(g: &Context, s: &mut ParamStore, has_grad: &[bool], grad_scale: f32) -> Vec<adam::GroupStep> {
    let mut rec = g.recorder("adam").expect("recorder");
    let report = adam::step(&mut rec, s, has_grad, grad_scale).expect("adam step");
    rec.submit_and_wait().expect("submit");
    report
}

fn assert_close(got: &[f32], want: &[f64], what: &str) {
    for (i, (a, b)) in got.iter().zip(want).enumerate() {
        assert!(close_f32(*a, *b as f32), "{what}[{i}]: got {a} want {b}");
    }
}

#[test]
fn four_steps_match_hand_computed_values() {
    // torch.optim.Adam(lr=0.01, betas=(0.9, 0.999), eps=1e-8), constant lr, values computed in f64:
    //   m = 0.9 m + 0.1 g; v = 0.999 v + 0.001 g²; p -= 0.01 / (1 - 0.9^t) * m / (sqrt(v) / sqrt(1 - 0.999^t) + 1e-8)
    let g = gpu();
    let mut grp = ParamGroup::new("all", 0.01, 0.01, 0);
    grp.adam = AdamHyper { beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.0 };
    let mut s = store(&g, vec![grp], vec![SlotDesc::new("w", SlotKind::Zeros { len: 3 }, "all")], None);
    set(&s, "w", false, &[1.0, -2.0, 0.5]);
    let grads = [[0.1, -0.2, 0.0], [0.3, 0.1, 0.0], [-0.2, 0.05, 0.0], [0.0, 0.0, 1.0]];
    let want_p = [
        [0.9900000009999999, -1.9900000005, 0.5],
        [0.9808221902205589, -1.9873366302718676, 0.5],
        [0.9782431522889793, -1.9867227416903714, 0.5],
        [0.9761305613601561, -1.9862198815242607, 0.494188716494219],
    ];
    let want_m = [[0.01, -0.02, 0.0], [0.039, -0.008, 0.0], [0.0151, -0.0022, 0.0], [0.01359, -0.00198, 0.1]];
    let want_v = [
        [1.0e-05, 4.0e-05, 0.0],
        [9.999e-05, 4.996e-05, 0.0],
        [0.00013989001, 5.241004e-05, 0.0],
        [0.00013975011999, 5.235762996e-05, 0.001],
    ];
    for t in 0..4 {
        set(&s, "w", true, &grads[t]);
        let rep = step(&g, &mut s, &[true], 1.0);
        assert_eq!(rep[0].t, t as u64 + 1);
        assert_close(&get(&s, "w", "p"), &want_p[t], &format!("params after step {}", t + 1));
        assert_close(&get(&s, "w", "m"), &want_m[t], &format!("m after step {}", t + 1));
        assert_close(&get(&s, "w", "v"), &want_v[t], &format!("v after step {}", t + 1));
    }
    // The first step moves every parameter with a gradient by lr against its sign.
    assert!((want_p[0][0] - 1.0 + 0.01).abs() < 1e-8 && (want_p[0][1] + 2.0 - 0.01).abs() < 1e-8);
}

#[test]
fn schedule_weight_decay_and_grad_scale_match_hand_computed_values() {
    // lr0 0.1 -> lr_final 0.01 over 4 scheduler steps: 0.1, 10^-1.25, 10^-1.5; weight decay 0.1 added to the
    // (scaled by 0.5) gradient; eps 1e-15. Values computed in f64.
    let g = gpu();
    let mut grp = ParamGroup::new("decay", 0.1, 0.01, 4);
    grp.adam.weight_decay = 0.1;
    let mut s = store(&g, vec![grp], vec![SlotDesc::new("w", SlotKind::Zeros { len: 2 }, "decay")], None);
    set(&s, "w", false, &[0.25, -1.5]);
    let grads = [[2.0, -4.0], [1.0, 1.0], [-0.5, 0.0]];
    let lrs = [0.1, 0.05623413251903493, 0.0316227766016838];
    let want_p = [[0.15, -1.4], [0.09753968367302215, -1.3697516355748316], [0.07936530828469346, -1.3553607870747624]];
    let want_m = [[0.1025, -0.215], [0.14375, -0.1575], [0.1053503968367302, -0.1554475163557483]];
    let want_v =
        [[0.001050625, 0.0046225], [0.001314799375, 0.0047474775], [0.00137120273134026, 0.004761492217931602]];
    for t in 0..3 {
        set(&s, "w", true, &grads[t]);
        let rep = step(&g, &mut s, &[true], 0.5);
        assert!((rep[0].lr - lrs[t]).abs() < 1e-15, "lr at step {t}: {}", rep[0].lr);
        assert_close(&get(&s, "w", "p"), &want_p[t], &format!("params after step {}", t + 1));
        assert_close(&get(&s, "w", "m"), &want_m[t], &format!("m after step {}", t + 1));
        assert_close(&get(&s, "w", "v"), &want_v[t], &format!("v after step {}", t + 1));
    }
    assert_eq!(s.schedule_step(), 3);
}

#[test]
fn exponential_decay_matches_nerfacto() {
    let fields = ParamGroup::new("fields", 1e-2, 1e-4, 200_000);
    assert_eq!(fields.lr_at(0), 1e-2);
    // nerfacto.md §1.1: ≈ 5.0e-3 at step 30000 (τ = 0.15): 10^(-2·0.85 - 4·0.15) = 10^-2.3.
    assert!((fields.lr_at(30_000) - 10f64.powf(-2.3)).abs() < 1e-15);
    assert!((fields.lr_at(200_000) - 1e-4).abs() < 1e-18 && fields.lr_at(400_000) == fields.lr_at(200_000));
    let camera = ParamGroup::new("camera", 1e-3, 1e-4, 5_000);
    assert!((camera.lr_at(2_500) - 10f64.powf(-3.5)).abs() < 1e-17);
    assert!((camera.lr_at(5_000) - 1e-4).abs() < 1e-18 && (camera.lr_at(9_999) - 1e-4).abs() < 1e-18);
    assert_eq!(ParamGroup::new("frozen", 0.0, 1e-4, 10).lr_at(3), 0.0);
}

#[test]
fn run_schedule_follows_the_run_progress() {
    // `optimizer.schedule: run`: a group with `over_run` takes its rate at the run's progress once the trainer sets
    // one; other groups (the camera's) keep their step schedule. Expected values from the formula, in f64.
    let mut fields = ParamGroup::new("fields", 1e-2, 1e-3, 3_000);
    fields.over_run = true;
    assert!((fields.lr_at_progress(0.5) - 10f64.powf(-2.5)).abs() < 1e-16);
    assert_eq!(fields.lr_at_progress(1.0), 1e-3);
    assert_eq!(fields.lr_at_progress(7.0), 1e-3);
    assert_eq!(fields.lr_at_progress(f64::NAN), 1e-2);
    assert_eq!(fields.lr_at_progress(-1.0), 1e-2);
    let camera = ParamGroup::new("camera", 1e-3, 1e-4, 5_000);
    let g = gpu();
    let slots = vec![
        SlotDesc::new("w", SlotKind::Zeros { len: 8 }, "fields"),
        SlotDesc::new("c", SlotKind::Zeros { len: 6 }, "camera"),
    ];
    let mut s = store(&g, vec![fields, camera], slots, None);
    assert_eq!((s.lr(0), s.lr(1)), (1e-2, 1e-3), "no progress set: the step schedule");
    s.set_run_progress(Some(0.25));
    let want = 10f64.powf(-2.25);
    assert!((s.lr(0) - want).abs() < 1e-16 && s.lr(1) == 1e-3, "{} {}", s.lr(0), s.lr(1));
    set(&s, "w", true, &[1.0; 8]);
    set(&s, "c", true, &[1.0; 6]);
    let rep = step(&g, &mut s, &[true, true], 1.0);
    assert!((rep[0].lr - want).abs() < 1e-16 && rep[1].lr == 1e-3, "{rep:?}");
    // The first Adam step moves every parameter by lr (m / sqrt(v) = 1 after bias correction, eps 1e-15).
    for (p, lr) in [(get(&s, "w", "p"), want), (get(&s, "c", "p"), 1e-3)] {
        assert!(p.iter().all(|&x| (x as f64 + lr).abs() < 1e-7 * (1.0 + lr)), "{p:?} against -{lr}");
    }
    // The trainer's progress: the larger of steps over the step budget and seconds over the time budget.
    use msnerf::nerf::trainer::run_progress;
    assert_eq!(run_progress(50, 100, 10.0, Some(40.0)), 0.5);
    assert_eq!(run_progress(10, 100, 30.0, Some(40.0)), 0.75);
    assert_eq!(run_progress(10, 100, 30.0, None), 0.1);
    assert_eq!(run_progress(200, 100, 0.0, None), 1.0);
    assert_eq!(run_progress(0, 0, 0.0, None), 1.0);
}

#[test]
fn kernel_matches_twin_across_groups_and_chunks() {
    let g = gpu();
    let mut fields = ParamGroup::new("fields", 1e-2, 1e-4, 20);
    fields.adam.eps = 1e-15;
    let proposal = ParamGroup::new("proposal", 5e-3, 5e-3, 0);
    let mut camera = ParamGroup::new("camera", 1e-3, 1e-4, 3);
    camera.adam = AdamHyper { beta1: 0.8, beta2: 0.99, eps: 1e-8, weight_decay: 1e-2 };
    let mlp = |dims: &[(usize, usize)]| SlotKind::Mlp {
        matrices: dims.iter().map(|&(fan_in, fan_out)| MatrixShape { fan_in, fan_out }).collect(),
    };
    let slots = vec![
        SlotDesc::new("grid", SlotKind::HashTable { len: 70_001 }, "fields"),
        SlotDesc::new("density mlp", mlp(&[(32, 64), (64, 16)]), "fields"),
        SlotDesc::new("color mlp", mlp(&[(64, 64), (64, 64), (64, 16)]), "fields"),
        SlotDesc::new("appearance", SlotKind::Embedding { rows: 50, dim: 32 }, "fields"),
        SlotDesc::new("proposal grid", SlotKind::HashTable { len: 9_000 }, "proposal"),
        SlotDesc::new("proposal mlp", mlp(&[(16, 16), (16, 16)]), "proposal"),
        SlotDesc::new("camera", SlotKind::Zeros { len: 6 * 50 }, "camera"),
    ];
    // Chunks of 2^14 elements: the fields group spans several chunks, groups share chunks.
    let mut s = store(&g, vec![fields, proposal, camera], slots, Some(14));
    assert!(s.len() > 90_000 && s.params().chunks().len() >= 6, "{} elements", s.len());
    let layout = s.layout().clone();
    let mut p = s.params().download(&g).expect("params");
    let (mut m, mut v) = (vec![0.0f32; p.len()], vec![0.0f32; p.len()]);
    let mut r = rng(21);
    let mut t = [0u64; 3];
    let plan: [([bool; 3], f32); 5] = [
        ([true, true, true], 1.0),
        ([true, false, true], 1.0),
        ([true, true, true], 0.5),
        ([true, false, false], 1.0),
        ([true, true, true], 2.0),
    ];
    for (it, (has_grad, scale)) in plan.iter().enumerate() {
        let mut rec = g.recorder("zero").expect("recorder");
        s.zero_grads(&mut rec).expect("zero grads");
        rec.submit_and_wait().expect("submit");
        let mut grads = vec![0.0f32; p.len()];
        for slot in layout.slots().iter().filter(|sl| has_grad[sl.group]) {
            let gr: Vec<f32> = (0..slot.len).map(|_| r.random_range(-1.0..1.0) * 1e-2).collect();
            grads[slot.range()].copy_from_slice(&gr);
            s.upload_slot(s.grads(), slot, &gr).expect("grads");
        }
        let rep = step(&g, &mut s, has_grad, *scale);
        for gi in 0..3 {
            let lr = s.groups()[gi].lr_at(it as u64);
            assert_eq!(rep[gi].lr, lr);
            assert_eq!(rep[gi].stepped, has_grad[gi]);
            if !has_grad[gi] {
                continue;
            }
            t[gi] += 1;
            let sc = AdamScalars::<f32>::new(&s.groups()[gi].adam, lr, t[gi], *scale as f64);
            let rg = layout.group_range(gi);
            adam_step(&mut p[rg.clone()], &grads[rg.clone()], &mut m[rg.clone()], &mut v[rg.clone()], &sc);
        }
    }
    assert_eq!(s.group_steps(), &[5, 3, 4]);
    assert_eq!(s.schedule_step(), 5);
    assert_all_close_f32(&s.params().download(&g).expect("p"), &p, "params");
    assert_all_close_f32(&s.m().download(&g).expect("m"), &m, "m");
    assert_all_close_f32(&s.v().download(&g).expect("v"), &v, "v");
}

#[test]
fn twin_f32_follows_f64() {
    let mut r = rng(22);
    let n = 1000;
    let p0: Vec<f64> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
    let h = AdamHyper::default();
    let (mut p64, mut m64, mut v64) = (p0.clone(), vec![0.0; n], vec![0.0; n]);
    let mut p32: Vec<f32> = p0.iter().map(|&x| x as f32).collect();
    let (mut m32, mut v32) = (vec![0.0f32; n], vec![0.0f32; n]);
    for t in 1..=10 {
        let g64: Vec<f64> = (0..n).map(|_| r.random_range(-1.0..1.0)).collect();
        let g32: Vec<f32> = g64.iter().map(|&x| x as f32).collect();
        adam_step(&mut p64, &g64, &mut m64, &mut v64, &AdamScalars::new(&h, 1e-2, t, 1.0));
        adam_step(&mut p32, &g32, &mut m32, &mut v32, &AdamScalars::new(&h, 1e-2, t, 1.0));
    }
    let want: Vec<f32> = p64.iter().map(|&x| x as f32).collect();
    assert_all_close_f32(&p32, &want, "f32 twin vs f64 twin");
}

#[test]
fn eps_1e15_with_zero_and_vanishing_gradients_stays_finite() {
    let g = gpu();
    let mut s = store(
        &g,
        vec![ParamGroup::new("fields", 1e-2, 1e-4, 100)],
        vec![SlotDesc::new("w", SlotKind::Zeros { len: 4 }, "fields")],
        None,
    );
    set(&s, "w", false, &[0.5, -0.5, 1.0, 0.0]);
    // One real gradient, then vanishing ones (their squares underflow to 0 in f32), then exact zeros.
    let seq: [[f32; 4]; 4] = [[1.0, 0.0, 1e-30, 0.0], [1e-30, 1e-38, 0.0, 0.0], [0.0; 4], [0.0; 4]];
    let mut before = get(&s, "w", "p");
    for (i, gr) in seq.iter().cycle().take(24).enumerate() {
        set(&s, "w", true, gr);
        step(&g, &mut s, &[true], 1.0);
        let p = get(&s, "w", "p");
        assert!(p.iter().chain(&get(&s, "w", "m")).chain(&get(&s, "w", "v")).all(|x| x.is_finite()), "step {i}: {p:?}");
        // Adam moves a parameter by at most lr (1 - b1) / sqrt(1 - b2) per step (≈ 3.2 lr), never more.
        for (a, b) in p.iter().zip(&before) {
            assert!((a - b).abs() <= 3.2e-2 * 1.01, "step {i}: moved {} ", a - b);
        }
        before = p;
    }
    // An element that never had a gradient has not moved at all.
    assert_eq!(before[3], 0.0);
}

#[test]
fn zero_lr_and_skipped_groups_change_nothing() {
    let g = gpu();
    let groups = vec![ParamGroup::new("frozen", 0.0, 1e-4, 10), ParamGroup::new("live", 1e-2, 1e-2, 0)];
    let slots = vec![
        SlotDesc::new("a", SlotKind::HashTable { len: 1000 }, "frozen"),
        SlotDesc::new("b", SlotKind::HashTable { len: 1000 }, "live"),
    ];
    let mut s = store(&g, groups, slots, None);
    let mut r = rng(23);
    let a0 = get(&s, "a", "p");
    let b0 = get(&s, "b", "p");
    for _ in 0..3 {
        let gr: Vec<f32> = (0..1000).map(|_| r.random_range(-1.0..1.0)).collect();
        set(&s, "a", true, &gr);
        set(&s, "b", true, &gr);
        let rep = step(&g, &mut s, &[true, true], 1.0);
        assert!(!rep[0].stepped && rep[1].stepped);
    }
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&get(&s, "a", "p")), bits(&a0), "lr 0 must leave parameters bit-identical");
    assert!(get(&s, "a", "m").iter().chain(&get(&s, "a", "v")).all(|&x| x == 0.0), "lr 0 must leave moments alone");
    assert_ne!(get(&s, "b", "p"), b0);
    assert_eq!(s.group_steps(), &[0, 3]);
    // A group without a gradient this iteration: nothing moves, its counter stays.
    let (b1, m1, v1) = (get(&s, "b", "p"), get(&s, "b", "m"), get(&s, "b", "v"));
    let rep = step(&g, &mut s, &[true, false], 1.0);
    assert!(!rep[1].stepped && rep[1].t == 3);
    assert_eq!(bits(&get(&s, "b", "p")), bits(&b1));
    assert_eq!(bits(&get(&s, "b", "m")), bits(&m1));
    assert_eq!(bits(&get(&s, "b", "v")), bits(&v1));
    assert_eq!(s.group_steps(), &[0, 3]);
    assert_eq!(s.schedule_step(), 4, "the schedule advances every call");
    // Wrong number of flags: an error, nothing recorded.
    let mut rec = g.recorder("bad").expect("recorder");
    assert!(adam::step(&mut rec, &mut s, &[true], 1.0).is_err());
    assert_eq!(s.schedule_step(), 4);
}

#[test]
fn a_slot_larger_than_one_binding_is_stepped_chunk_by_chunk() {
    // Default chunks (as large as one binding: 128 MiB on lavapipe): a hash table a little longer than one chunk
    // starts on a chunk boundary and spans two; Adam dispatches once per chunk piece with ordinary bindings.
    let g = gpu();
    // Capped at 2^25 elements (128 MiB) so that a device with 4 GiB bindings does not allocate 16 GiB here.
    let shift = msnerf::nn::params::default_chunk_shift(&g).min(25);
    let chunk = 1usize << shift;
    let len = chunk + 4_099;
    let slots = vec![
        SlotDesc::new("mlp", SlotKind::Zeros { len: 100 }, "fields"),
        SlotDesc::new("grid", SlotKind::HashTable { len }, "fields"),
    ];
    let mut s = store(&g, vec![ParamGroup::new("fields", 1e-2, 1e-4, 100)], slots, Some(shift));
    let grid = s.slot("grid").expect("slot").clone();
    assert_eq!(grid.offset, chunk, "a slot longer than a chunk starts on a chunk boundary");
    assert_eq!(s.params().chunks().len(), 3);
    let p0 = s.download_slot(s.params(), &grid).expect("p0");
    let grads: Vec<f32> = (0..len).map(|i| ((i % 7) as f32 - 3.0) * 1e-3).collect();
    s.upload_slot(s.grads(), &grid, &grads).expect("grads");
    step(&g, &mut s, &[true], 1.0);
    let got = s.download_slot(s.params(), &grid).expect("p1");
    let mut want = p0.clone();
    let (mut m, mut v) = (vec![0.0f32; len], vec![0.0f32; len]);
    let sc = AdamScalars::<f32>::new(&s.groups()[0].adam, 1e-2, 1, 1.0);
    adam_step(&mut want, &grads, &mut m, &mut v, &sc);
    assert_all_close_f32(&got, &want, "params across two chunks");
    assert_all_close_f32(&s.download_slot(s.v(), &grid).expect("v"), &v, "v across two chunks");
}

#[test]
fn a_set_gate_skips_the_step_on_the_device_and_undo_step_restores_the_counters() {
    // The training step's NaN guard runs Adam in the same submission as the gradient check (issue 22): a set flag
    // must leave parameters and both moments bitwise as they were, a clear one must step exactly as ungated Adam.
    let g = gpu();
    let mut grp = ParamGroup::new("all", 0.01, 0.01, 0);
    grp.adam = AdamHyper { beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.0 };
    let slots = vec![SlotDesc::new("w", SlotKind::Zeros { len: 1003 }, "all")];
    let mut gated = store(&g, vec![grp.clone()], slots.clone(), None);
    let mut plain = store(&g, vec![grp], slots, None);
    let mut r = rng(4);
    let p0: Vec<f32> = (0..1003).map(|_| r.random_range(-1.0f32..1.0)).collect();
    let g0: Vec<f32> = (0..1003).map(|_| r.random_range(-1.0f32..1.0)).collect();
    for s in [&gated, &plain] {
        set(s, "w", false, &p0);
        set(s, "w", true, &g0);
    }
    let flag =
        msnerf::gpu::GpuBuffer::from_slice(&g, "gate", msnerf::gpu::MemoryCategory::Other, &[1u32]).expect("flag");
    let mut rec = g.recorder("gated adam").expect("rec");
    let report = adam::step_gated(&mut rec, &mut gated, &[true], 1.0, Some(&flag)).expect("step");
    rec.submit_and_wait().expect("submit");
    assert!(report[0].stepped && gated.group_steps()[0] == 1 && gated.schedule_step() == 1, "counters advance");
    assert_eq!(get(&gated, "w", "p"), p0, "a set gate leaves the parameters");
    assert!(get(&gated, "w", "m").iter().chain(&get(&gated, "w", "v")).all(|&x| x == 0.0), "and the moments");
    gated.undo_step(&report);
    assert_eq!((gated.group_steps()[0], gated.schedule_step()), (0, 0), "undo_step takes the counters back");

    g.upload(&flag, 0, &[0u32]).expect("clear");
    let mut rec = g.recorder("gated adam").expect("rec");
    adam::step_gated(&mut rec, &mut gated, &[true], 1.0, Some(&flag)).expect("step");
    rec.submit_and_wait().expect("submit");
    step(&g, &mut plain, &[true], 1.0);
    for w in ["p", "m", "v"] {
        assert_eq!(get(&gated, "w", w), get(&plain, "w", w), "a clear gate steps as ungated Adam ({w})");
    }
    assert_eq!(gated.group_steps(), plain.group_steps());
}
