#!/usr/bin/env bash
# Issue 50's acceptance (`make flight-acceptance`, `make flight-acceptance-paper`): a flight written by the sensor in
# the simulator (MicaSense RedEdge-MX files of the flight-rural scene, with a panel capture, GPS noise and a datum
# shift) through `msnerf process` from its card, the same flight written directly by the simulator trained and
# exported the same way, and every product of both compared with the truth (`msnerf bench flight`).
#
#   [MSNERF=binary] [GCP=n] tools/flight-acceptance.sh [ci|paper] [OUT] [TRAIN_SECONDS]
#
# GCP=n (default 0): n ground control points in the flight's gcp_list.txt, given to `process` (the products are then
# judged as delivered; without them after removing the GPS's stated datum shift).
# ci: flight-rural, 30 captures of 320x240 (about 15 minutes on 2 cores with lavapipe), and the same flight written
# directly by the simulator beside it; paper: flight-rural-large, 300 captures of 1280x960 (an hour or more on a
# CPU; the time and host memory of every stage are the point there, so the DSM and ortho are made at the CI
# flight's cell size, 0.11 m, unless SURVEY_GSD says otherwise, and the direct flight is left out). The JSON goes to
# docs/results/log/flight-acceptance-<size>-<date>.json; docs/results/flight.md quotes it.
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:-ci}
out=${2:-flight-acceptance-$size}
budget=${3:-300}
bin=${MSNERF:-target/release/msnerf}
gcp=${GCP:-0}
case "$size" in
  ci) sim=(--width 320) ; scene=flight-rural ; extra=() ; direct=1 ;;
  paper) sim=() ; scene=configs/scenes/flight-rural-large.yaml ; extra=(--gsd "${SURVEY_GSD:-0.11}") ; direct=0 ;;
  *) echo "flight-acceptance: size must be ci or paper, got $size" >&2; exit 2 ;;
esac
mkdir -p "$out" docs/results/log
echo "== simulate (${sim[*]})"
$bin simulate --scene "$scene" --raw-rig micasense-rededge "${sim[@]}" --gcp "$gcp" --out "$out/flight" --overwrite
if [ "$gcp" -gt 0 ]; then extra+=(--gcp "$out/flight/gcp_list.txt"); fi
# The panel's calibration sheet, band reflectances in wavelength order.
panel=$(python3 -c 'import json,sys; b=json.load(open(sys.argv[1]))["bands"]; print(",".join(str(x["reflectance"]) for x in sorted(b, key=lambda x: x["center_nm"])))' "$out/flight/truth/panel.json")
echo "== process (panel reflectance $panel, $budget s of training)"
$bin process "$out/flight/card" --out "$out/project" --panel-reflectance "$panel" --time-budget "$budget" --model demo "${extra[@]}"
gsd=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["summary"]["gsd"])' "$out/project/stages/survey.json")
args=(--flight "$out/flight" --project "$out/project")
if [ "$direct" = 1 ]; then
  echo "== the same flight written directly by the simulator: train, eval, export (gsd $gsd)"
  rm -rf "$out/direct-run" "$out/direct-products"
  mkdir -p "$out/direct-products"
  $bin train --data "$out/flight/truth/dataset" --model demo --time-budget "$budget" --out "$out/direct-run" --quiet
  $bin eval "$out/direct-run"
  $bin export pointcloud "$out/direct-run" --out "$out/direct-products/cloud.las"
  $bin export dsm "$out/direct-run" --gsd "$gsd" --out "$out/direct-products/dsm.tif"
  args+=(--direct-run "$out/direct-run" --direct-products "$out/direct-products")
fi
echo "== compare with the truth"
json="docs/results/log/flight-acceptance-$size$([ "$gcp" -gt 0 ] && echo "-gcp")-$(date +%F).json"
$bin bench flight "${args[@]}" --json > "$out/acceptance.json"
cp "$out/acceptance.json" "$json"
$bin bench flight "${args[@]}"
echo "wrote $json"
