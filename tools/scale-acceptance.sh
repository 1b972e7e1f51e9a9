#!/usr/bin/env bash
# Issue 23's acceptance on the built-in campus scene: one run against a 2x2 block partition at the same total steps.
# Simulates campus with 20,000 SfM-like sparse points (as tools/geometry-report.sh does), trains the demo profile
# with DS-NeRF depth supervision for STEPS steps as one run, partitions the flight 2x2 (overlap 0.15) and trains each
# block for STEPS/4 steps (`msnerf train-blocks`, one at a time), then exports both clouds (the careful export) and
# both DSMs on the truth's grid, and compares them with the simulator's ground truth (compare-cloud, compare-raster).
# Writes docs/results/log/scale-acceptance-<date>.json and prints the verdict: the merged cloud's median accuracy and
# completeness within 10 % of the single run's, and no point in two blocks' cores (checked by the merge itself).
# About 20 minutes on 2 cores with lavapipe at the default 8000 steps. Usage: tools/scale-acceptance.sh [WORKDIR] [STEPS]
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-scale-acceptance-output}
steps=${2:-8000}
bin=./target/release/msnerf
[ -x "$bin" ] || { echo "scale-acceptance: build first (make build)" >&2; exit 1; }
mkdir -p "$work"
t0=$(date +%s)
"$bin" simulate --scene campus --out "$work/data" --sparse-points 20000 --sparse-noise 0.1 --overwrite
sed 's/^name: demo$/name: demo-sfm/; s/^  distortion_mult: \(.*\)$/  distortion_mult: \1\n  depth: {loss: ds_nerf, source: sparse_points, mult: 1.0e-3, sigma: 0.2, ray_fraction: 0.25}/' \
  configs/models/demo.yaml > "$work/demo-sfm.yaml"
grep -q "depth: {loss: ds_nerf" "$work/demo-sfm.yaml" || { echo "scale-acceptance: could not add loss.depth" >&2; exit 1; }
per_block=$((steps / 4))
rm -rf "$work/single" "$work/blocks"  # a rerun starts over
ts=$(date +%s)
"$bin" train --data "$work/data" --model "$work/demo-sfm.yaml" --max-steps "$steps" --out "$work/single" --quiet \
  | tee "$work/train-single.txt"
single_s=$(( $(date +%s) - ts ))
"$bin" partition "$work/data" --blocks 2x2 --overlap 0.15 --out "$work/blocks" | tee "$work/partition.txt"
ts=$(date +%s)
"$bin" train-blocks "$work/blocks" -- --model "$work/demo-sfm.yaml" --max-steps "$per_block" | tee "$work/train-blocks.txt"
blocks_s=$(( $(date +%s) - ts ))
"$bin" export pointcloud "$work/single" --out "$work/single.ply" | tee "$work/export-single.txt"
"$bin" export pointcloud "$work/blocks" --out "$work/merged.ply" | tee "$work/export-merged.txt"
truth="$work/data/truth"
"$bin" export dsm "$work/single" --align-to "$truth/dsm.tif" --out "$work/dsm-single.tif" | tee "$work/dsm-single.txt"
"$bin" export dsm "$work/blocks" --align-to "$truth/dsm.tif" --out "$work/dsm-merged.tif" | tee "$work/dsm-merged.txt"
for v in single merged; do
  "$bin" compare-cloud --pred "$work/$v.ply" --ref "$work/data/ground_truth.ply" --within 0.1,0.21,0.42,0.63 --json \
    > "$work/compare-$v.json"
  "$bin" compare-raster --pred "$work/dsm-$v.tif" --ref "$truth/dsm.tif" --classes "$truth/classes.tif" \
    --within 0.18,0.36,0.72 --json > "$work/compare-dsm-$v.json"
done
out="docs/results/log/scale-acceptance-$(date -u +%Y-%m-%d).json"
python3 - "$work" "$steps" "$per_block" "$single_s" "$blocks_s" "$(( $(date +%s) - t0 ))" "$out" <<'EOF'
import json, platform, sys
work, steps, per_block, single_s, blocks_s, total_s, out = sys.argv[1:]
def load(name):
    with open(f"{work}/{name}") as f:
        return json.load(f)
rows = {}
for v in ("single", "merged"):
    c, d = load(f"compare-{v}.json"), load(f"compare-dsm-{v}.json")
    rows[v] = {
        "points": c["pred_points"],
        "accuracy_median_m": c["accuracy"]["median"],
        "completeness_median_m": c["completeness"]["median"],
        "f_score_0.1": c["f_score"],
        "rmse_planar_m": c["position"]["rmse_planar"],
        "rmse_elevation_m": c["position"]["rmse_elevation"],
        "dsm_median_abs_m": d["bands"][0]["median_abs"] if "bands" in d else None,
    }
ratio = {k: rows["merged"][k] / rows["single"][k] for k in ("accuracy_median_m", "completeness_median_m")}
verdict = all(r <= 1.10 for r in ratio.values())
report = {
    "scene": "campus (built-in), 20,000 sparse points, demo profile + DS-NeRF depth",
    "steps_single": int(steps), "steps_per_block": int(per_block), "blocks": "2x2, overlap 0.15",
    "seconds": {"single_training": int(single_s), "blocks_training": int(blocks_s), "whole_script": int(total_s)},
    "machine": f"{platform.node()} ({platform.machine()}), lavapipe",
    "single": rows["single"], "merged": rows["merged"],
    "merged_over_single": ratio,
    "within_10_percent": verdict,
}
with open(out, "w") as f:
    json.dump(report, f, indent=2)
print(json.dumps(report, indent=2))
print(f"scale acceptance: {'PASS' if verdict else 'FAIL'} (merged / single: accuracy {ratio['accuracy_median_m']:.3f}, "
      f"completeness {ratio['completeness_median_m']:.3f}) -> {out}")
EOF
