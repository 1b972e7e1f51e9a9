//! The parameter store: layout invariants (no slot crosses a chunk; alignment; contiguous groups), the
//! initialisation statistics of every slot kind and their seed reproducibility, save/load round trips (bit-exact,
//! across chunk sizes) and the errors for corrupted, truncated and mismatched files.

use crate::common;
use common::{gpu, rng};
use msnerf::gpu::Context;
use msnerf::nn::adam;
use msnerf::nn::params::{
    Checksum, MatrixShape, ParamError, ParamGroup, ParamLayout, ParamStore, ParamStoreDesc, SlotDesc, SlotKind,
    SLOT_ALIGN,
};
use rand::Rng;
use std::path::PathBuf;

fn mlp(dims: &[(usize, usize)]) -> SlotKind {
    SlotKind::Mlp { matrices: dims.iter().map(|&(fan_in, fan_out)| MatrixShape { fan_in, fan_out }).collect() }
}

fn groups() -> Vec<ParamGroup> {
    vec![
        ParamGroup::new("fields", 1e-2, 1e-4, 200_000),
        ParamGroup::new("proposal", 1e-2, 1e-4, 200_000),
        ParamGroup::new("camera", 1e-3, 1e-4, 5_000),
    ]
}

/// A nerfacto-like model, small.
fn slots() -> Vec<SlotDesc> {
    vec![
        SlotDesc::new("grid", SlotKind::HashTable { len: 50_000 }, "fields"),
        SlotDesc::new("camera", SlotKind::Zeros { len: 60 }, "camera"),
        SlotDesc::new("density mlp", mlp(&[(32, 64), (64, 16)]), "fields"),
        SlotDesc::new("proposal grid", SlotKind::HashTable { len: 3_000 }, "proposal"),
        SlotDesc::new("color mlp", mlp(&[(64, 64), (64, 64), (64, 16)]), "fields"),
        SlotDesc::new("appearance", SlotKind::Embedding { rows: 100, dim: 32 }, "fields"),
        SlotDesc::new("proposal mlp", mlp(&[(16, 16), (16, 1)]), "proposal"),
    ]
}

fn new_store(g: &Context, slots: Vec<SlotDesc>, seed: u64, chunk_shift: Option<u32>) -> ParamStore {
    ParamStore::new(g, &ParamStoreDesc { name: "model", groups: groups(), slots, seed, chunk_shift })
        .expect("param store")
}

/// A fresh folder under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        let p = std::env::temp_dir().join(format!("msnerf-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).expect("temp dir");
        Self(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn layout_keeps_slots_inside_chunks() {
    let shift = 10;
    let chunk = 1usize << shift;
    let sizes = [10, 1000, 1024, 1025, 3000, 64, 63, 500, 700, 2048, 1, 960];
    let descs: Vec<SlotDesc> = sizes
        .iter()
        .enumerate()
        .map(|(i, &n)| SlotDesc::new(&format!("s{i}"), SlotKind::HashTable { len: n }, &groups()[i % 3].name))
        .collect();
    let l = ParamLayout::new(&groups(), &descs, shift).expect("layout");
    assert_eq!(l.slots().len(), sizes.len());
    let mut prev_end = 0;
    for s in l.slots() {
        assert_eq!(s.offset % SLOT_ALIGN, 0, "{} unaligned", s.name);
        assert!(s.offset >= prev_end, "{} overlaps the slot before it", s.name);
        if s.len <= chunk {
            assert_eq!(s.offset / chunk, (s.offset + s.len - 1) / chunk, "{} crosses a chunk boundary", s.name);
        } else {
            assert_eq!(s.offset % chunk, 0, "{} is longer than a chunk and must start on a boundary", s.name);
        }
        prev_end = s.offset + s.len;
    }
    assert_eq!(l.len(), prev_end);
    // Groups are contiguous, in declaration order, with their slots in declaration order.
    for gi in 0..3 {
        let mine: Vec<_> = l.slots().iter().filter(|s| s.group == gi).collect();
        let r = l.group_range(gi);
        assert_eq!(r.start, mine[0].offset);
        assert_eq!(r.end, mine.last().expect("slots").range().end);
        assert!(l.slots().iter().filter(|s| s.group != gi).all(|s| s.range().end <= r.start || s.offset >= r.end));
        let names: Vec<&str> = mine.iter().map(|s| s.name.as_str()).collect();
        let want: Vec<String> = (0..sizes.len()).filter(|i| i % 3 == gi).map(|i| format!("s{i}")).collect();
        assert_eq!(names, want);
    }
    // chunk_ranges partitions a range into in-chunk pieces.
    let pieces = l.chunk_ranges(100..5000);
    assert_eq!(pieces.iter().map(|(_, r)| r.len()).sum::<usize>(), 4900);
    assert!(pieces.iter().all(|(_, r)| r.end <= chunk));
    assert_eq!(pieces[0], (0, 100..1024));
    assert_eq!(pieces.last().expect("pieces").0, 4);
    // Bad descriptions are refused.
    let bad = |d: Vec<SlotDesc>| ParamLayout::new(&groups(), &d, shift).is_err();
    assert!(bad(vec![SlotDesc::new("a", SlotKind::Zeros { len: 1 }, "nope")]), "unknown group");
    assert!(bad(vec![SlotDesc::new("a", SlotKind::Zeros { len: 0 }, "fields")]), "empty slot");
    assert!(bad(vec![SlotDesc::new("a", mlp(&[(0, 4)]), "fields")]), "empty matrix");
    let dup = SlotDesc::new("a", SlotKind::Zeros { len: 1 }, "fields");
    assert!(bad(vec![dup.clone(), dup]), "repeated name");
    assert!(ParamLayout::new(&groups(), &slots(), 3).is_err(), "chunks smaller than the alignment");
}

#[test]
fn store_arrays_bind_slots_within_chunks() {
    let g = gpu();
    let s = new_store(&g, slots(), 1, Some(14));
    assert!(s.params().chunks().len() >= 4);
    for a in [s.params(), s.grads(), s.m(), s.v()] {
        assert_eq!(a.len(), s.len());
        assert_eq!(a.chunk_shift(), 14);
    }
    for sl in s.slots() {
        let b = s.slot_binding(s.params(), sl);
        assert_eq!(b.is_ok(), sl.len <= 1 << 14, "{}: {b:?}", sl.name);
    }
    let report = g.memory_report();
    let cat = |c| report.categories.iter().find(|x| x.category == c).expect("category").current;
    use msnerf::gpu::MemoryCategory as M;
    assert!(cat(M::Parameters) >= 4 * s.len() as u64 && cat(M::Gradients) >= 4 * s.len() as u64);
    assert!(cat(M::OptimizerState) >= 8 * s.len() as u64);
}

fn mean_var(v: &[f32]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().map(|&x| x as f64).sum::<f64>() / n;
    (mean, v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n)
}

fn check_uniform(v: &[f32], a: f64, what: &str) {
    let (mean, var) = mean_var(v);
    let n = v.len() as f64;
    let want_var = a * a / 3.0;
    assert!(v.iter().all(|&x| (x as f64).abs() <= a), "{what}: a value outside ±{a}");
    assert!(mean.abs() < 5.0 * (want_var / n).sqrt(), "{what}: mean {mean}");
    // Var of the sample variance of U(-a, a): (a^4/5 - a^4/9) / n.
    let sd_var = (a.powi(4) * (1.0 / 5.0 - 1.0 / 9.0) / n).sqrt();
    assert!((var - want_var).abs() < 5.0 * sd_var, "{what}: var {var} want {want_var}");
}

#[test]
fn init_statistics_per_slot_kind_and_seed_reproducibility() {
    let g = gpu();
    let s = new_store(&g, slots(), 42, Some(14));
    let all = s.params().download(&g).expect("params");
    let get = |name: &str| all[s.slot(name).expect("slot").range()].to_vec();
    check_uniform(&get("grid"), 1e-4, "hash table");
    check_uniform(&get("proposal grid"), 1e-4, "proposal hash table");
    for name in ["density mlp", "color mlp", "proposal mlp"] {
        let v = get(name);
        let SlotKind::Mlp { matrices } = &s.slot(name).expect("slot").kind else { panic!("mlp slot") };
        let mut o = 0;
        for (i, m) in matrices.iter().enumerate() {
            let n = m.fan_in * m.fan_out;
            let a = (6.0 / (m.fan_in + m.fan_out) as f64).sqrt();
            if n >= 256 {
                check_uniform(&v[o..o + n], a, &format!("{name} matrix {i}"));
            } else {
                assert!(v[o..o + n].iter().all(|&x| (x as f64).abs() <= a), "{name} matrix {i} bounds");
            }
            o += n;
        }
    }
    let e = get("appearance");
    let (mean, var) = mean_var(&e);
    let n = e.len() as f64;
    assert!(mean.abs() < 5.0 / n.sqrt() && (var - 1.0).abs() < 5.0 * (2.0 / n).sqrt(), "N(0,1): {mean} {var}");
    assert!(e.iter().any(|&x| x.abs() > 2.5), "normal tails");
    assert!(get("camera").iter().all(|&x| x == 0.0));
    // Padding is zero; gradients and moments are zero.
    let mut covered = vec![false; all.len()];
    for sl in s.slots() {
        covered[sl.range()].iter_mut().for_each(|c| *c = true);
    }
    assert!(all.iter().zip(&covered).all(|(&x, &c)| c || x == 0.0), "padding must be zero");
    for a in [s.grads(), s.m(), s.v()] {
        assert!(a.download(&g).expect("download").iter().all(|&x| x == 0.0), "{} must start at zero", a.name());
    }
    // Same seed: bit-identical, whatever the chunk size. Other seed: different. A slot's values do not depend on
    // the other slots.
    let same = new_store(&g, slots(), 42, None);
    let other = new_store(&g, slots(), 43, Some(14));
    let only_grid = new_store(&g, vec![slots()[0].clone()], 42, None);
    for sl in s.slots() {
        let a = get(&sl.name);
        let b = same.download_slot(same.params(), same.slot(&sl.name).expect("slot")).expect("download");
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "{} not reproducible", sl.name);
        if !matches!(sl.kind, SlotKind::Zeros { .. }) {
            assert_ne!(a, other.download_slot(other.params(), other.slot(&sl.name).expect("slot")).expect("download"));
        }
    }
    let grid = only_grid.download_slot(only_grid.params(), only_grid.slot("grid").expect("slot")).expect("grid");
    assert_eq!(grid, get("grid"));
}

/// A store that has taken a few Adam steps, so moments and counters are not zero.
fn trained_store(g: &Context, seed: u64, chunk_shift: Option<u32>) -> ParamStore {
    let mut s = new_store(g, slots(), seed, chunk_shift);
    let mut r = rng(seed);
    for it in 0..3 {
        let mut rec = g.recorder("zero").expect("recorder");
        s.zero_grads(&mut rec).expect("zero");
        rec.submit_and_wait().expect("submit");
        for sl in s.slots().to_vec() {
            let gr: Vec<f32> = (0..sl.len).map(|_| r.random_range(-1.0..1.0)).collect();
            s.upload_slot(s.grads(), &sl, &gr).expect("grads");
        }
        let mut rec = g.recorder("adam").expect("recorder");
        adam::step(&mut rec, &mut s, &[true, it != 1, true], 1.0).expect("step");
        rec.submit_and_wait().expect("submit");
    }
    s
}

fn bits_of(s: &ParamStore, g: &Context) -> Vec<Vec<u32>> {
    let _ = g;
    let mut out = Vec::new();
    for sl in s.slots() {
        for a in [s.params(), s.m(), s.v()] {
            out.push(s.download_slot(a, sl).expect("download").iter().map(|x| x.to_bits()).collect());
        }
    }
    out
}

#[test]
fn save_load_round_trip_is_bit_exact() {
    let g = gpu();
    let dir = TempDir::new("params-roundtrip");
    let path = dir.0.join("model.params");
    let a = trained_store(&g, 7, Some(14));
    assert_eq!(a.group_steps(), &[3, 2, 3]);
    a.save(&path).expect("save");
    // Saving again replaces the file atomically and leaves no temporary behind.
    a.save(&path).expect("save over");
    let names: Vec<_> = std::fs::read_dir(&dir.0).expect("dir").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("model.params")]);
    // Into a store with another seed, and one with another chunk size (other offsets, same slots).
    for shift in [Some(14), Some(12), None] {
        let mut b = new_store(&g, slots(), 99, shift);
        b.load(&path).expect("load");
        assert_eq!(b.group_steps(), a.group_steps());
        assert_eq!(b.schedule_step(), 3);
        assert!(bits_of(&b, &g) == bits_of(&a, &g), "round trip differs (chunk shift {shift:?})");
    }
}

fn assert_format_error(r: Result<(), ParamError>, what: &str) {
    match r {
        Err(ParamError::Format { msg, .. }) => eprintln!("{what}: {msg}"),
        other => panic!("{what}: expected a format error, got {other:?}"),
    }
}

#[test]
fn corrupted_truncated_and_mismatched_files_are_errors() {
    let g = gpu();
    let dir = TempDir::new("params-corrupt");
    let good = dir.0.join("good.params");
    trained_store(&g, 3, None).save(&good).expect("save");
    let bytes = std::fs::read(&good).expect("read");
    let mut s = new_store(&g, slots(), 11, None);
    let before = bits_of(&s, &g);
    let write = |name: &str, b: &[u8]| {
        let p = dir.0.join(name);
        std::fs::write(&p, b).expect("write");
        p
    };
    // A flipped bit in the data, in the header, in the checksum.
    for at in [bytes.len() / 2, 20, bytes.len() - 3] {
        let mut b = bytes.clone();
        b[at] ^= 0x10;
        assert_format_error(s.load(&write("flip.params", &b)), &format!("bit flip at {at}"));
    }
    // Truncated anywhere, and empty.
    for len in [0, 5, 30, bytes.len() / 3, bytes.len() - 1] {
        assert_format_error(s.load(&write("short.params", &bytes[..len])), &format!("truncated to {len}"));
    }
    // Not a parameter file at all.
    let text = b"this is a text file that happens to be longer than the header of a parameter file";
    assert_format_error(s.load(&write("foreign.params", text)), "foreign file");
    // Well-formed checksums over bad content: bad magic, unknown version.
    let resum = |mut b: Vec<u8>| {
        let n = b.len() - 8;
        let mut c = Checksum::new();
        c.update(&b[..n]);
        b[n..].copy_from_slice(&c.finish().to_le_bytes());
        b
    };
    let mut b = bytes.clone();
    b[0] = b'X';
    assert_format_error(s.load(&write("magic.params", &resum(b))), "bad magic");
    let mut b = bytes.clone();
    b[8] = 9;
    assert_format_error(s.load(&write("version.params", &resum(b))), "unknown version");
    assert!(matches!(s.load(&dir.0.join("missing.params")), Err(ParamError::Io { .. })));
    // Nothing was written into the store by any failed load.
    assert!(bits_of(&s, &g) == before, "a failed load changed the store");
    assert_eq!(s.group_steps(), &[0, 0, 0]);
    // A model whose layout differs: the error names the slot.
    let mut changed = slots();
    changed[5] = SlotDesc::new("appearance", SlotKind::Embedding { rows: 101, dim: 32 }, "fields");
    let mut other = new_store(&g, changed, 1, None);
    match other.load(&good) {
        Err(e @ ParamError::LayoutMismatch { .. }) => {
            assert!(e.to_string().contains("\"appearance\""), "{e}");
        }
        r => panic!("expected a layout mismatch, got {r:?}"),
    }
    let mut renamed = slots();
    renamed[2].name = "density net".into();
    let err = new_store(&g, renamed, 1, None).load(&good).expect_err("renamed slot");
    assert!(err.to_string().contains("density net"), "{err}");
    let mut fewer = slots();
    fewer.pop();
    let err = new_store(&g, fewer, 1, None).load(&good).expect_err("missing slot");
    assert!(err.to_string().contains("proposal mlp"), "{err}");
}
