#!/usr/bin/env bash
# `make rig-parallax`: issue 19's rig-aware training experiment (docs/radiometry.md, "Rig-aware training").
# The built-in rig-low scene (a rig flown 5 m over crates and shrubs, band cameras 2-6 cm beside the green one) is
# simulated once and trained four ways for the same time budget: rig-aware (the dataset's rig_cameras), warped
# (`msnerf dataset register`: one homography per band and frame, the import's alignment), shared (one median
# homography per band for the whole flight, as `import rig --register rig` and ODM) and naive (the unwarped bands
# treated as one camera: `--no-rig-cameras`). Each run is scored against the registered truth the simulator writes.
# Writes docs/results/log/rig-parallax-<date>.json. Usage: tools/rig-parallax.sh [WORK_DIR] [SECONDS_PER_RUN] (~15 min at 200).
set -euo pipefail
cd "$(dirname "$0")/.."
work="${1:-rig-parallax-output}"
budget="${2:-200}"
bin=./target/release/msnerf
rm -rf "$work"
mkdir -p "$work"
$bin simulate --scene rig-low --out "$work/aware"
$bin dataset register "$work/aware" --out "$work/warped" > "$work/register-warped.json"
$bin dataset register "$work/aware" --out "$work/shared" --shared > "$work/register-shared.json"
for v in aware warped shared naive; do
  # naive: the rig-aware dataset with its rig_cameras ignored (the unwarped bands taken as one camera).
  data="$work/$v" flag=""
  [ "$v" = naive ] && data="$work/aware" flag="--no-rig-cameras"
  $bin train --data "$data" $flag --model tiny --out "$work/run-$v" --max-steps 100000 --time-budget "$budget" --quiet
  $bin eval "$work/run-$v" --registered-truth "$work/aware/truth/registered" --output "$work/run-$v/eval.json"
done
out="docs/results/log/rig-parallax-$(date -u +%Y-%m-%d).json"
{
  printf '{\n"machine": "%s",\n"date": "%s",\n"budget_s": %s,\n"register_warped": %s,\n"register_shared": %s,\n' \
    "$(uname -m), $(nproc) cores" "$(date -u +%Y-%m-%d)" "$budget" "$(cat "$work/register-warped.json")" \
    "$(cat "$work/register-shared.json")"
  for v in aware warped shared naive; do
    printf '"%s": {"train": %s,\n"eval": %s,\n"registered": %s}' "$v" "$(cat "$work/run-$v/summary.json")" \
      "$(cat "$work/run-$v/eval.json")" "$(cat "$work/run-$v/eval_registered.json")"
    [ "$v" = naive ] && printf '\n}\n' || printf ',\n'
  done
} > "$out.tmp"
mv "$out.tmp" "$out"
echo "wrote $out"
