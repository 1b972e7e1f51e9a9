#!/usr/bin/env bash
# Survey-export benchmark (issue 21): simulate the campus scene with its SfM points, train the `demo` profile with
# DS-NeRF depth for SECONDS, then time `msnerf export dsm --ortho` twice: on the truth's grid (0.361 m cells,
# compared with the truth per class), and over the same area at BIG_GSD (a large raster: rows per second and the
# peak host memory, which the export prints). Prints every number; JSON and logs land in OUT.
#   usage: tools/survey-bench.sh [OUT] [SECONDS] [BIG_GSD]      (defaults: survey-bench-output 120 0.1)
#   MSNERF=path/to/msnerf overrides the binary (default target/release/msnerf).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-survey-bench-output}; secs=${2:-120}; big=${3:-0.1}
bin=${MSNERF:-./target/release/msnerf}
mkdir -p "$out"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$bin" devices | head -n 3 | tee "$out/device.txt"
"$bin" simulate --scene campus --out "$work/data" --sparse-points 20000 --sparse-noise 0.1 > /dev/null
sed 's/^  distortion_mult: \(.*\)$/  distortion_mult: \1\n  depth: {loss: ds_nerf, source: sparse_points, mult: 1.0e-3, sigma: 0.2, ray_fraction: 0.25}/' \
  configs/models/demo.yaml > "$work/demo-sfm.yaml"
"$bin" train --data "$work/data" --model "$work/demo-sfm.yaml" --time-budget "$secs" --out "$work/run" --quiet \
  | tail -n 2 | tee "$out/train.txt"
t=$work/data/truth
"$bin" export dsm "$work/run" --align-to "$t/dsm.tif" --out "$work/dsm.tif" --ortho "$work/ortho.tif" | grep -v '^->' \
  | tee "$out/export-truth-grid.txt"
"$bin" compare-raster --pred "$work/dsm.tif" --ref "$t/dsm.tif" --classes "$t/classes.tif" --within 0.18,0.36,0.72 \
  --output "$out/compare-dsm.json" | head -n 4
"$bin" compare-raster --pred "$work/ortho.tif" --ref "$t/ortho.tif" --classes "$t/classes.tif" --peak 1 \
  --output "$out/compare-ortho.json" | head -n 7
"$bin" export ortho "$work/run" --gsd "$big" --out "$work/big-ortho.tif" --dsm "$work/big-dsm.tif" --indices ndvi \
  | grep -v '^->' | tee "$out/export-big.txt"
ls -l "$work"/big-*.tif | awk '{print $5, $9}' | tee -a "$out/export-big.txt"
echo "survey bench: $out"
