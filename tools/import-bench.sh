#!/usr/bin/env bash
# `make import-bench`: `msnerf bench import` on the real RedEdge flight capture of tests/fixtures/real, replicated
# 16 times, written to docs/results/log/bench-import-<date>.json (docs/radiometry.md §6 quotes it).
set -euo pipefail
cd "$(dirname "$0")/.."
real="${MSNERF_REAL_DATA:-tests/fixtures/real}/micasense-rededge"
[ -d "$real" ] || { echo "import-bench: $real not found (set MSNERF_REAL_DATA to a folder holding micasense-rededge/)" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cp "$real"/0000SET_IMG_0001_*.tif "$work"/
out="docs/results/log/bench-import-$(date -u +%Y-%m-%d).json"
./target/release/msnerf bench import "$work" --replicate 16 --json > "$out.tmp"
mv "$out.tmp" "$out"
cat "$out"
