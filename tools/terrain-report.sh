#!/usr/bin/env bash
# Regenerates docs/results/terrain.md's figures (`make terrain-report`): simulate the campus with 20,000 SfM-like
# sparse points, train the `demo` profile (depth supervision from the points, the default) for SECONDS, export the DSM
# and true ortho on the truth's grid, then the DTM, CHM and trees, and compare each with the simulator's truth.
# The JSON and the commands' output land in docs/results/log/terrain-campus-<date>/. About 15 minutes on 2 cores
# with lavapipe. Usage: tools/terrain-report.sh [WORKDIR] [SECONDS]
set -euo pipefail
cd "$(dirname "$0")/.."
work=${1:-terrain-report-output}
secs=${2:-600}
bin=${MSNERF:-./target/release/msnerf}
log=docs/results/log/terrain-campus-$(date +%F)
mkdir -p "$work" "$log"
"$bin" simulate --scene campus --out "$work/data" --sparse-points 20000 --sparse-noise 0.1 --overwrite
rm -rf "$work/run" "$work/p"
"$bin" train --data "$work/data" --model demo --time-budget "$secs" --out "$work/run" | tee "$work/train.txt"
p="$work/p"
mkdir -p "$p"
truth="$work/data/truth"
{
  "$bin" export dsm "$work/run" --align-to "$truth/dsm.tif" --out "$p/dsm.tif" --ortho "$p/ortho.tif"
  "$bin" export dtm --dsm "$p/dsm.tif" --out "$p/dtm.tif"
  "$bin" export chm --dsm "$p/dsm.tif" --dtm "$p/dtm.tif" --out "$p/chm.tif"
  "$bin" export trees --chm "$p/chm.tif" --dtm "$p/dtm.tif" --ortho "$p/ortho.tif" --out "$p/trees.geojson"
} | grep -v '^->' | tee "$log/products.txt"
for x in dsm dtm chm; do
  "$bin" compare-raster --pred "$p/$x.tif" --ref "$truth/$x.tif" --classes "$truth/classes.tif" --quality "$p/${x}_quality.tif" \
    --json > "$log/compare-$x.json"
done
"$bin" compare-trees --pred "$p/trees.geojson" --truth "$truth/trees.geojson" --classes "$truth/classes.tif" --json \
  > "$log/compare-trees.json"
"$bin" compare-trees --pred "$p/trees.geojson" --truth "$truth/trees.geojson" --classes "$truth/classes.tif"
cp "$p/trees.csv" "$log/trees.csv"
echo "terrain report: $log"
