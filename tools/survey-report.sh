#!/usr/bin/env bash
# Regenerates docs/geometry.md's survey-product numbers and pictures (issue 21) from the two ten-minute campus runs
# of tools/geometry-report.sh (images only, and with the SfM points): for each, `msnerf export dsm --ortho` on the
# grid of the simulator's truth (`--align-to truth/dsm.tif`, so every cell is compared with its own truth cell),
# `msnerf compare-raster` against truth/dsm.tif and truth/ortho.tif per class (open ground, roofs: interior cells)
# and the DSM per material (truth/materials.tif: dark, bright and uniform surfaces apart), the previews, and the
# truth's own previews (`msnerf preview`). Results land in docs/geometry/survey/. About two
# minutes on 2 cores with lavapipe. Usage: tools/survey-report.sh [WORKDIR]  (default geometry-report-output)
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-geometry-report-output}
bin=./target/release/msnerf
out=docs/geometry/survey
truth="$work/data/truth"
for f in dsm.tif ortho.tif classes.tif materials.tif; do
  # (a report made before materials.tif existed lacks it: run geometry-report again)
  [ -f "$truth/$f" ] || { echo "survey-report: $truth/$f missing: run 'make geometry-report'" >&2; exit 1; }
done
mkdir -p "$out" "$work/survey"
for variant in images sfm; do
  run="$work/run-$variant"
  [ -d "$run" ] || { echo "survey-report: $run missing: run 'make geometry-report' first" >&2; exit 1; }
  "$bin" export dsm "$run" --align-to "$truth/dsm.tif" --out "$work/survey/dsm-$variant.tif" \
    --ortho "$work/survey/ortho-$variant.tif" | tee "$out/export-$variant.txt"
  "$bin" compare-raster --pred "$work/survey/dsm-$variant.tif" --ref "$truth/dsm.tif" --classes "$truth/classes.tif" \
    --within 0.18,0.36,0.72 --json > "$out/compare-dsm-$variant.json"
  "$bin" compare-raster --pred "$work/survey/dsm-$variant.tif" --ref "$truth/dsm.tif" \
    --classes "$truth/materials.tif" --within 0.18,0.36,0.72 --json > "$out/compare-dsm-materials-$variant.json"
  "$bin" compare-raster --pred "$work/survey/ortho-$variant.tif" --ref "$truth/ortho.tif" --classes "$truth/classes.tif" \
    --peak 1 --within 0.02,0.05 --json > "$out/compare-ortho-$variant.json"
  gdalinfo "$work/survey/dsm-$variant.tif" > "$out/gdalinfo-dsm-$variant.txt"
done
"$bin" preview "$truth/dsm.tif" && "$bin" preview "$truth/ortho.tif"
# The page's pictures: the run with the SfM points beside the truth (the other previews stay in $work/survey).
for p in dsm-sfm_hillshade ortho-sfm_rgb ortho-sfm_ndvi; do cp "$work/survey/$p.png" "$out/"; done
for p in dsm_hillshade ortho_rgb ortho_ndvi; do cp "$truth/${p}.png" "$out/truth_$p.png"; done
echo "survey report: $out"
