#!/usr/bin/env bash
# Runs a suite packed by tools/package-tests.sh on this machine's GPU, with the validation layer required (tests
# fail on any message) unless MSNERF_WITHOUT_LAYER=1. Give it the checkout (a copy of the repository at the commit
# the package was built from): the tests read tests/ files and launch target/release/msnerf under the path they
# were built at, so that path is made to point at the checkout when it differs.
#   usage: run-packaged-tests.sh PACKAGE.tar.xz CHECKOUT LOG_DIR [TEST_BINARY...]
# Prints one line per test binary (exit code, seconds, cargo's summary) and writes each binary's output to LOG_DIR.
# A build path that exists and is not a link is left alone (the run stops). Needs root only to create the build
# path's parent when it is missing.
set -uo pipefail
[ $# -ge 3 ] || { sed -n '2,8p' "$0"; exit 2; }
package="$1"; checkout="$(cd "$2" && pwd)"; logs="$3"; shift 3
work="$(mktemp -d)"
tar -xJf "$package" -C "$work"
pkg="$work/msnerf-tests"
built_at="$(cat "$pkg/BUILT_AT")"
if [ "$checkout" != "$built_at" ]; then
  if [ -e "$built_at" ] && [ ! -L "$built_at" ]; then
    echo "$built_at exists and is not a link: run from the checkout at that path" >&2
    exit 1
  fi
  mkdir -p "$(dirname "$built_at")" && ln -sfn "$checkout" "$built_at" \
    || { echo "cannot link $built_at to $checkout" >&2; exit 1; }
fi
mkdir -p "$logs"
# The tests launch target/release/msnerf: the packaged one, unless the checkout has its own cargo build.
if [ ! -d "$checkout/target/release/.fingerprint" ]; then
  mkdir -p "$checkout/target/release" && cp "$pkg/msnerf" "$checkout/target/release/msnerf"
fi
export LD_LIBRARY_PATH="$pkg/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
# MSNERF_WITHOUT_LAYER=1 runs without the packed validation layer: for a package built with the tensor-core kernels
# (tools/package-tests.sh, MSNERF_FEATURES), which Debian 12's layer predates and so keeps off.
if [ "${MSNERF_WITHOUT_LAYER:-0}" = 1 ]; then
  echo "run-packaged-tests: validation layer off (MSNERF_WITHOUT_LAYER=1)"
else
  export VK_LAYER_PATH="$pkg/layers"
  export MSNERF_REQUIRE_VALIDATION=1
fi
export MSNERF_POISON_BUFFERS=1
nv=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$nv" ] && [ -z "${VK_DRIVER_FILES:-}" ] && export VK_DRIVER_FILES="$nv"
"$checkout/target/release/msnerf" devices || { echo "no Vulkan device: install the GPU's Vulkan driver" >&2; exit 1; }
tests=("$@")
[ ${#tests[@]} -gt 0 ] || mapfile -t tests < <(ls "$pkg" | grep -v -e '^lib$' -e '^layers$' -e '^msnerf$' -e '\.sh$' -e '^BUILT_AT$')
failed=0
cd "$built_at"
for t in "${tests[@]}"; do
  start=$(date +%s)
  "$pkg/$t" > "$logs/$t.log" 2>&1; rc=$?
  [ $rc -eq 0 ] || failed=$((failed + 1))
  echo "$t rc=$rc $(( $(date +%s) - start ))s $(grep -E '^test result' "$logs/$t.log" | tail -1)"
done
echo "$failed of ${#tests[@]} test binaries failed"
[ $failed -eq 0 ]
