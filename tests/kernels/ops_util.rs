//! Utility kernels against their CPU twins (`msnerf::reference::util`), on sizes that are not multiples of the
//! workgroup and on sizes that need more than 65535 groups (folded 2D dispatch).
//! Tolerance: u32 exact; f32 |a-b| <= 1e-5 + 1e-4|b| (in practice bit-exact: the twins add in kernel order).

use crate::common;
use common::{assert_all_close_f32, gpu, random_f32, random_u32, rng};
use msnerf::gpu::{BufferDesc, Context, GpuBuffer, MemoryCategory};
use msnerf::ops::{self, ScanValue};
use msnerf::reference::util as twin;

/// 65535 groups of 256 plus some: the first size that needs a folded grid.
const PAST_GROUP_LIMIT: usize = 65_535 * 256 + 1_001;
const SIZES: [usize; 7] = [1, 7, 255, 256, 257, 4_099, 70_001];

fn buf<T: bytemuck::Pod>(g: &Context, name: &str, data: &[T]) -> GpuBuffer<T> {
    GpuBuffer::from_slice(g, name, MemoryCategory::Other, data).expect("upload")
}

fn empty<T: bytemuck::Pod>(g: &Context, name: &str, len: usize) -> GpuBuffer<T> {
    GpuBuffer::new(g, &BufferDesc { name, len, category: MemoryCategory::Other }).expect("buffer")
}

#[test]
fn fill_and_copy_match_twins() {
    let g = gpu();
    let mut r = rng(1);
    for &n in SIZES.iter().chain([PAST_GROUP_LIMIT].iter()) {
        let init = random_u32(&mut r, n + 40);
        let a = buf(&g, "a", &init);
        let b = buf(&g, "b", &init.iter().map(|v| v ^ 0xffff).collect::<Vec<_>>());
        let mut rec = g.recorder("fill copy").expect("recorder");
        ops::fill(&mut rec, &a, 0xdead_beefu32, 13, n).expect("fill");
        ops::copy(&mut rec, &a, 5, &b, 20, n).expect("copy");
        rec.submit_and_wait().expect("submit");
        let mut want_a = init.clone();
        twin::fill(&mut want_a, 0xdead_beef, 13, n);
        let mut want_b: Vec<u32> = init.iter().map(|v| v ^ 0xffff).collect();
        twin::copy(&want_a, 5, &mut want_b, 20, n);
        common::assert_same(&g.download(&a).expect("a"), &want_a, &format!("fill n={n}"));
        common::assert_same(&g.download(&b).expect("b"), &want_b, &format!("copy n={n}"));
    }
    // f32 through the 32-bit pattern.
    let f = empty::<f32>(&g, "f", 300);
    let mut rec = g.recorder("fill f32").expect("recorder");
    ops::fill(&mut rec, &f, -1.5f32, 0, 300).expect("fill");
    rec.submit_and_wait().expect("submit");
    assert!(g.download(&f).expect("f").iter().all(|&v| v == -1.5));
}

fn check_reduce<V: ScanValue + twin::WrappingAdd + PartialEq>(g: &Context, data: &[V], f32_cmp: impl Fn(V, V) -> bool) {
    let a = buf(g, "in", data);
    let got = ops::sum(g, &a, data.len()).expect("sum");
    let want = twin::reduce_sum(data);
    assert!(f32_cmp(got, want), "n={}: got {got:?} want {want:?}", data.len());
}

#[test]
fn reduce_sum_matches_twin() {
    let g = gpu();
    let mut r = rng(2);
    for &n in SIZES.iter().chain([0, PAST_GROUP_LIMIT].iter()) {
        let f = random_f32(&mut r, n, -1.0, 1.0);
        check_reduce(&g, &f, common::close_f32);
        // The twin is also close to the exact (f64) sum: the tree keeps rounding error small.
        let exact: f64 = f.iter().map(|&v| v as f64).sum();
        assert!((twin::reduce_sum(&f) as f64 - exact).abs() <= 1e-6 * (n as f64).max(1.0));
        let u = random_u32(&mut r, n);
        check_reduce(&g, &u, |a, b| a == b);
    }
}

#[test]
fn exclusive_scan_matches_twin() {
    let g = gpu();
    let mut r = rng(3);
    // 65793 = 257 blocks: three recursion levels.
    for &n in SIZES.iter().chain([65_793, PAST_GROUP_LIMIT].iter()) {
        let u: Vec<u32> = random_u32(&mut r, n).iter().map(|v| v % 1000).collect();
        let a = buf(&g, "u", &u);
        let out = empty::<u32>(&g, "out", n);
        let mut rec = g.recorder("scan u32").expect("recorder");
        ops::exclusive_scan(&mut rec, &a, &out, n).expect("scan");
        rec.submit_and_wait().expect("submit");
        let want = twin::exclusive_scan(&u);
        common::assert_same(&g.download(&out).expect("out"), &want, &format!("u32 scan n={n}"));
        // The twin is a true exclusive scan.
        let mut acc = 0u32;
        for (i, &v) in u.iter().enumerate() {
            assert_eq!(want[i], acc);
            acc = acc.wrapping_add(v);
        }
        if n > 300_000 {
            continue; // f32 at this size: covered by u32; keeps the suite fast on 2 cores
        }
        let f = random_f32(&mut r, n, 0.0, 1.0);
        let fa = buf(&g, "f", &f);
        let mut rec = g.recorder("scan f32 in place").expect("recorder");
        ops::exclusive_scan(&mut rec, &fa, &fa, n).expect("scan in place");
        rec.submit_and_wait().expect("submit");
        assert_all_close_f32(&g.download(&fa).expect("f"), &twin::exclusive_scan(&f), &format!("f32 scan n={n}"));
    }
}

#[test]
fn segmented_scan_matches_twin() {
    let g = gpu();
    let mut r = rng(4);
    // Ray-like segments: empty ones, single samples, 48..256 samples, and one long one.
    let mut lens: Vec<u32> = vec![0, 1, 48, 96, 256, 0, 3, 1000];
    lens.extend((0..5000).map(|i| [0, 1, 48, 96, 256, 17][i % 6]));
    let mut starts = vec![0u32];
    for l in &lens {
        starts.push(starts.last().copied().unwrap_or(0) + l);
    }
    let n = *starts.last().expect("nonempty") as usize;
    let segs = lens.len();
    let f = random_f32(&mut r, n, 0.0, 2.0);
    let u: Vec<u32> = random_u32(&mut r, n);
    let st = buf(&g, "starts", &starts);
    let (fv, uv) = (buf(&g, "f", &f), buf(&g, "u", &u));
    let (fo, uo) = (empty::<f32>(&g, "fo", n), empty::<u32>(&g, "uo", n));
    let (ft, ut) = (empty::<f32>(&g, "ft", segs), empty::<u32>(&g, "ut", segs));
    let mut rec = g.recorder("segmented").expect("recorder");
    ops::segmented_exclusive_scan(&mut rec, &fv, &st, &fo, &ft, segs).expect("f32");
    ops::segmented_exclusive_scan(&mut rec, &uv, &st, &uo, &ut, segs).expect("u32");
    rec.submit_and_wait().expect("submit");
    let (wf, wft) = twin::segmented_exclusive_scan(&f, &starts);
    let (wu, wut) = twin::segmented_exclusive_scan(&u, &starts);
    assert_all_close_f32(&g.download(&fo).expect("fo"), &wf, "segmented f32");
    assert_all_close_f32(&g.download(&ft).expect("ft"), &wft, "segment totals f32");
    common::assert_same(&g.download(&uo).expect("uo"), &wu, "segmented u32");
    common::assert_same(&g.download(&ut).expect("ut"), &wut, "segment totals u32");
    assert_eq!(wft[0], 0.0, "an empty segment sums to zero");
    assert_eq!(wf[starts[2] as usize], 0.0, "each segment restarts at zero");
}

#[test]
fn check_finite_flags_every_kind_of_non_finite_value_anywhere() {
    // Sizes off the workgroup and a large one (4 M floats: 256 groups of 256 invocations reading 64 each); one NaN,
    // +Inf or -Inf at the first, a middle and the last element (only inside 0..n counts), or none at all.
    let g = gpu();
    let mut r = rng(9);
    let big = (1 << 22) + 3;
    let flag = buf(&g, "flag", &[0u32]);
    for &n in SIZES.iter().chain([big].iter()) {
        let clean = random_f32(&mut r, n + 5, -1e30, 1e30);
        let cases: Vec<(Option<usize>, f32)> = std::iter::once((None, 0.0))
            .chain(
                [0, n / 2, n - 1]
                    .into_iter()
                    .flat_map(|i| [f32::NAN, f32::INFINITY, f32::NEG_INFINITY].map(|v| (Some(i), v))),
            )
            .chain([(Some(n), f32::NAN)]) // past n: not looked at
            .collect();
        let data = buf(&g, "data", &clean);
        for (at, v) in cases {
            let mut host = clean.clone();
            if let Some(i) = at {
                host[i] = v;
            }
            g.upload(&data, 0, &host).expect("upload");
            let mut rec = g.recorder("check").expect("rec");
            ops::fill(&mut rec, &flag, 0u32, 0, 1).expect("zero flag");
            ops::record_check_finite(&mut rec, &data, n, &flag).expect("check");
            rec.submit_and_wait().expect("submit");
            let got = g.download(&flag).expect("flag")[0] == 1;
            assert_eq!(got, twin::any_non_finite(&host[..n]), "n {n}, {v} at {at:?}");
        }
    }
}

#[test]
fn check_finite_names_its_slot_and_a_gated_check_runs_only_after_a_hit() {
    // The training step's guard (src/nerf/guard.rs): ungated checks set flag 0 and their own slot; gated ones look
    // only when flag 0 is already set, so a clean step pays a few no-op dispatches and a poisoned one names its
    // buffers in the same submission.
    let g = gpu();
    let mut host = vec![0.5f32; 1000];
    host[777] = f32::NAN;
    let poisoned = buf(&g, "poisoned", &host);
    let clean = buf(&g, "clean", &vec![0.5f32; 1000]);
    let flags = buf(&g, "flags", &[0u32; 4]);
    let run = |first: &[(&GpuBuffer<f32>, usize, bool)]| -> Vec<u32> {
        let mut rec = g.recorder("check slots").expect("rec");
        ops::fill(&mut rec, &flags, 0u32, 0, 4).expect("zero");
        for &(data, slot, gated) in first {
            ops::record_check_finite_slot(&mut rec, data, 1000, &flags, slot, gated).expect("check");
        }
        rec.submit_and_wait().expect("submit");
        g.download(&flags).expect("flags")
    };
    assert_eq!(run(&[(&poisoned, 2, true)]), [0, 0, 0, 0], "gated, flag 0 clear: not looked at");
    assert_eq!(run(&[(&clean, 1, false), (&poisoned, 2, true)]), [0, 0, 0, 0], "a clean ungated check sets nothing");
    assert_eq!(run(&[(&poisoned, 3, false)]), [1, 0, 0, 1], "ungated hit: flag 0 and its slot");
    assert_eq!(
        run(&[(&poisoned, 3, false), (&clean, 1, true), (&poisoned, 2, true)]),
        [1, 0, 1, 1],
        "after a hit the gated checks name only the poisoned buffer"
    );
    let too_far = {
        let mut rec = g.recorder("bad slot").expect("rec");
        ops::record_check_finite_slot(&mut rec, &clean, 1000, &flags, 4, false)
    };
    assert!(too_far.is_err_and(|e| e.to_string().contains("flag 4 of 4")), "a slot past the flags is refused");
}
