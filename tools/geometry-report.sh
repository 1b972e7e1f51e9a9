#!/usr/bin/env bash
# Regenerates the raw numbers behind docs/geometry.md's ten-minute table (issue 18): simulate the campus scene with
# 20,000 SfM-like sparse points (0.1 m noise), then train the `demo` profile for 600 s twice, on the images alone
# and with DS-NeRF depth supervision from the points (the settings of `msnerf demo`); for each, evaluate depth on
# the held-out views, export the default (photometrically refined) cloud, the same without the refinement
# (`--no-refine`, named `careful` in the files) and the legacy one, and compare each with the simulator's ground truth
# (to its local surface, compare-cloud's default). Results land in docs/geometry/ (JSON and text); the page quotes
# them. About 34 minutes on 2 cores with lavapipe. Usage: tools/geometry-report.sh [WORKDIR] [SECONDS]
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-geometry-report-output}
secs=${2:-600}
bin=./target/release/msnerf
out=docs/geometry
mkdir -p "$work" "$out"
"$bin" simulate --scene campus --out "$work/data" --sparse-points 20000 --sparse-noise 0.1 --overwrite
# The demo profile plus the depth loss `msnerf demo` uses.
sed 's/^name: demo$/name: demo-sfm/; s/^  distortion_mult: \(.*\)$/  distortion_mult: \1\n  depth: {loss: ds_nerf, source: sparse_points, mult: 1.0e-3, sigma: 0.2, ray_fraction: 0.25}/' \
  configs/models/demo.yaml > "$work/demo-sfm.yaml"
grep -q "depth: {loss: ds_nerf" "$work/demo-sfm.yaml" || { echo "geometry-report: could not add loss.depth to demo.yaml" >&2; exit 1; }
for variant in images sfm; do
  model=demo
  [ "$variant" = sfm ] && model="$work/demo-sfm.yaml"
  suffix=10min
  [ "$variant" = sfm ] && suffix=10min-sfm
  rm -rf "$work/run-$variant" # this script's own run from a previous report
  "$bin" train --data "$work/data" --model "$model" --time-budget "$secs" --out "$work/run-$variant" | tee "$work/train-$variant.txt"
  "$bin" eval "$work/run-$variant" --depth --output "$out/eval-$suffix.json"
  "$bin" export pointcloud "$work/run-$variant" --out "$work/careful-$variant.ply" --no-refine \
    | tee "$out/export-careful-$suffix.txt"
  "$bin" export pointcloud "$work/run-$variant" --out "$work/refined-$variant.ply" | tee "$out/export-refined-$suffix.txt"
  "$bin" export pointcloud "$work/run-$variant" --out "$work/legacy-$variant.ply" --legacy | tee "$out/export-legacy-$suffix.txt"
  for c in careful refined legacy; do
    "$bin" compare-cloud --pred "$work/$c-$variant.ply" --ref "$work/data/ground_truth.ply" --within 0.1,0.21,0.42,0.63 \
      --json > "$out/compare-$c-$suffix.json"
  done
  tail -n 2 "$work/train-$variant.txt" | head -n 1 > "$out/train-$suffix.txt"
done
echo "geometry report: $out"
