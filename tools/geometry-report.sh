#!/usr/bin/env bash
# Regenerates the raw numbers behind docs/geometry.md's ten-minute table (issue 18): simulate the campus scene, train
# the `demo` profile for 600 s, evaluate depth on the held-out views, export the careful and the legacy clouds and
# compare both with the simulator's ground truth. Results land in docs/geometry/ (JSON and text); the page quotes
# them. About 13 minutes on 2 cores with lavapipe. Usage: tools/geometry-report.sh [WORKDIR] [SECONDS]
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-geometry-report-output}
secs=${2:-600}
bin=./target/release/msnerf
out=docs/geometry
mkdir -p "$work" "$out"
"$bin" simulate --scene campus --out "$work/data"
"$bin" train --data "$work/data" --model demo --time-budget "$secs" --out "$work/run" | tee "$work/train.txt"
"$bin" eval "$work/run" --depth --output "$out/eval-10min.json"
"$bin" export pointcloud "$work/run" --out "$work/careful.ply" | tee "$out/export-careful-10min.txt"
"$bin" export pointcloud "$work/run" --out "$work/legacy.ply" --legacy | tee "$out/export-legacy-10min.txt"
for c in careful legacy; do
  "$bin" compare-cloud --pred "$work/$c.ply" --ref "$work/data/ground_truth.ply" --within 0.1,0.21,0.42,0.63 \
    --json > "$out/compare-$c-10min.json"
done
tail -n 2 "$work/train.txt" | head -n 1 > "$out/train-10min.txt"
echo "geometry report: $out"
