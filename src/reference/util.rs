//! CPU twins of the util kernels (`glsl/util/`). Reduce and scan follow the kernels' exact order of
//! additions (256-wide blocks, the same tree and Hillis-Steele steps), so f32 results match bit for bit on a
//! conforming device; tests still compare f32 with a tolerance.

use std::ops::Add;

const BLOCK: usize = 256;

pub fn fill<T: Copy>(data: &mut [T], value: T, start: usize, n: usize) {
    data[start..start + n].fill(value);
}

pub fn copy<T: Copy>(src: &[T], src_start: usize, dst: &mut [T], dst_start: usize, n: usize) {
    dst[dst_start..dst_start + n].copy_from_slice(&src[src_start..src_start + n]);
}

/// Twin of `ops::reduce_sum`: tree-reduce 256-element blocks, repeat until one value is left.
/// Twin of `check_finite`: whether any element is NaN or +-Inf (all-ones exponent).
pub fn any_non_finite(data: &[f32]) -> bool {
    data.iter().any(|v| v.to_bits() & 0x7f80_0000 == 0x7f80_0000)
}

pub fn reduce_sum<V: Copy + Default + WrappingAdd>(input: &[V]) -> V {
    if input.is_empty() {
        return V::default();
    }
    let mut cur = input.to_vec();
    loop {
        let partials: Vec<V> = cur
            .chunks(BLOCK)
            .map(|c| {
                let mut tile = [V::default(); BLOCK];
                tile[..c.len()].copy_from_slice(c);
                let mut stride = BLOCK / 2;
                while stride > 0 {
                    for i in 0..stride {
                        tile[i] = tile[i].wadd(tile[i + stride]);
                    }
                    stride /= 2;
                }
                tile[0]
            })
            .collect();
        if partials.len() == 1 {
            return partials[0];
        }
        cur = partials;
    }
}

/// Twin of `ops::exclusive_scan`.
pub fn exclusive_scan<V: Copy + Default + WrappingAdd>(input: &[V]) -> Vec<V> {
    let mut out = vec![V::default(); input.len()];
    let mut sums = Vec::with_capacity(input.len().div_ceil(BLOCK));
    for (b, c) in input.chunks(BLOCK).enumerate() {
        let mut tile = [V::default(); BLOCK];
        tile[..c.len()].copy_from_slice(c);
        let mut offset = 1;
        while offset < BLOCK {
            let prev = tile;
            for i in offset..BLOCK {
                tile[i] = prev[i].wadd(prev[i - offset]);
            }
            offset *= 2;
        }
        for i in 0..c.len() {
            out[b * BLOCK + i] = if i == 0 { V::default() } else { tile[i - 1] };
        }
        sums.push(tile[BLOCK - 1]);
    }
    if sums.len() > 1 {
        let offsets = exclusive_scan(&sums);
        for (i, o) in out.iter_mut().enumerate() {
            *o = o.wadd(offsets[i / BLOCK]);
        }
    }
    out
}

/// Twin of `ops::segmented_exclusive_scan`: returns (output, totals).
pub fn segmented_exclusive_scan<V: Copy + Default + WrappingAdd>(values: &[V], starts: &[u32]) -> (Vec<V>, Vec<V>) {
    let mut out = vec![V::default(); values.len()];
    let mut totals = Vec::with_capacity(starts.len().saturating_sub(1));
    for w in starts.windows(2) {
        let mut acc = V::default();
        for j in w[0] as usize..w[1] as usize {
            out[j] = acc;
            acc = acc.wadd(values[j]);
        }
        totals.push(acc);
    }
    (out, totals)
}

/// Addition as the kernels do it: IEEE for f32, modulo 2^32 for u32.
pub trait WrappingAdd: Add<Output = Self> + Sized {
    fn wadd(self, o: Self) -> Self;
}

impl WrappingAdd for f32 {
    fn wadd(self, o: Self) -> Self {
        self + o
    }
}

impl WrappingAdd for u32 {
    fn wadd(self, o: Self) -> Self {
        self.wrapping_add(o)
    }
}

impl WrappingAdd for f64 {
    fn wadd(self, o: Self) -> Self {
        self + o
    }
}
