//! A logical array larger than one storage binding (128 MiB on lavapipe), stored in chunks and addressed by a
//! kernel through its chunk table, written and read back exactly.

use crate::common;
use common::gpu;
use msnerf::gpu::{Kernel, LargeArray, MemoryCategory};
use msnerf::shaders;

msnerf::push_constants! {
    struct IotaPush { table: u64, n: u32, shift: u32, seed: u32, pad: u32 }
}

fn pattern(i: u32, seed: u32) -> u32 {
    i.wrapping_mul(2_654_435_761).wrapping_add(seed)
}

#[test]
fn chunked_array_over_128_mib_round_trips_exactly() {
    let g = gpu();
    let max = g.caps().max_storage_buffer_range as usize;
    // 160 MiB of u32 (on lavapipe: one full 128 MiB chunk and one of 32 MiB), and a ragged tail.
    let n = (max + (32 << 20)) / 4 + 12_345;
    let arr = LargeArray::<u32>::new(&g, "big grid", n, MemoryCategory::Parameters).expect("large array");
    assert!(arr.chunks().len() >= 2, "the array must span several bindings");
    assert!(arr.chunks().iter().all(|c| c.size_bytes() <= max as u64));
    let k = Kernel::<IotaPush>::new(&g, &shaders::LARGE_ARRAY_IOTA).expect("kernel");
    let push =
        IotaPush { table: arr.table_address().expect("bda"), n: n as u32, shift: arr.chunk_shift(), seed: 77, pad: 0 };
    let mut rec = g.recorder("iota").expect("recorder");
    rec.dispatch_named("large_array_iota", &k, &[], &arr.deps(), &push, n as u64).expect("dispatch");
    rec.submit_and_wait().expect("submit");
    let got = arr.download(&g).expect("download");
    assert_eq!(got.len(), n);
    if let Some(i) = (0..n).find(|&i| got[i] != pattern(i as u32, 77)) {
        panic!("element {i} (chunk {}) is {} not {}", i >> arr.chunk_shift(), got[i], pattern(i as u32, 77));
    }
}

#[test]
fn uploads_split_across_small_chunks() {
    let g = gpu();
    // Chunks of 2^10 elements: an upload at an odd offset crosses several of them.
    let arr = LargeArray::<f32>::with_chunk_shift(&g, "small chunks", 5000, MemoryCategory::Other, 10).expect("array");
    assert_eq!(arr.chunks().len(), 5);
    assert_eq!(arr.chunks()[4].len(), 5000 - 4 * 1024);
    let data: Vec<f32> = (0..3000).map(|i| i as f32 * 0.5 - 7.0).collect();
    arr.upload(&g, 999, &data).expect("upload");
    let got = arr.download(&g).expect("download");
    assert_eq!(&got[999..3999], &data[..]);
    assert!(arr.upload(&g, 4000, &data).is_err(), "past the end");
}
