#!/usr/bin/env bash
# Packs the release test binaries, the `msnerf` binary, the Vulkan loader and the Khronos validation layer into one
# tarball, to run the suite on a GPU machine that has no Rust toolchain (tools/run-packaged-tests.sh runs it).
# The binaries are stripped (about 26 MB compressed). Build here, on Debian 12; the target machine needs an x86-64
# glibc at least as new and its GPU's Vulkan driver.
#   usage: tools/package-tests.sh [OUT.tar.xz]      (default: target/msnerf-tests.tar.xz)
# MSNERF_FEATURES=shaderc-from-source builds with that cargo feature (the tensor-core MLP kernels; the first build
# compiles glslang and SPIRV-Tools, about 20 minutes on 2 cores). On the GPU, MSNERF_REQUIRE_COOPMAT=1 then makes
# their test fail where they do not run; run that binary without the validation layer (Debian's predates them).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-target/msnerf-tests.tar.xz}"
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
pkg="$stage/msnerf-tests"
mkdir -p "$pkg/lib" "$pkg/layers"

command -v python3 >/dev/null || { echo "package-tests: needs python3 (apt-get install python3)" >&2; exit 1; }
features=()
[ -n "${MSNERF_FEATURES:-}" ] && features=(--features "$MSNERF_FEATURES")
if [[ "${MSNERF_FEATURES:-}" == *shaderc-from-source* ]]; then
  # shaderc-sys needs cmake and a C++ compiler ($CXX or c++); it uses ninja when present (faster), make otherwise.
  for c in cmake "${CXX:-c++}"; do
    command -v "$c" >/dev/null || { echo "package-tests: shaderc-from-source needs $c: apt-get install -y cmake g++ ninja-build" >&2; exit 1; }
  done
  command -v ninja >/dev/null || echo "package-tests: note: ninja not found; shaderc builds with make (slower; apt-get install ninja-build)" >&2
fi
cargo build --release "${features[@]}"
# One line per test executable: path, target name, target kind (lib and bin unit tests get fixed names).
cargo test --release "${features[@]}" --no-run --message-format=json 2>/dev/null | python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["profile"]["test"]:
        print(m["executable"], m["target"]["name"], m["target"]["kind"][0])
' | while read -r exe name kind; do
  case "$kind" in lib) name=unit_lib ;; bin) name=unit_bin ;; esac
  strip -o "$pkg/$name" "$exe"
done
strip -o "$pkg/msnerf" target/release/msnerf

lib=/usr/lib/x86_64-linux-gnu
for f in "$lib/libvulkan.so.1" "$lib/libVkLayer_khronos_validation.so" \
  /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json; do
  [ -e "$f" ] || { echo "package-tests: $f not found: run tools/setup-debian.sh first" >&2; exit 1; }
done
cp -L "$lib/libvulkan.so.1" "$pkg/lib/"
strip -o "$pkg/lib/libVkLayer_khronos_validation.so" "$lib/libVkLayer_khronos_validation.so"
cp /usr/share/vulkan/explicit_layer.d/VkLayer_khronos_validation.json "$pkg/layers/"
cp tools/run-packaged-tests.sh "$pkg/"
# The checkout path baked into the binaries (tests read tests/ files and launch target/release/msnerf there).
pwd > "$pkg/BUILT_AT"

mkdir -p "$(dirname "$out")"
tar -C "$stage" -cf - msnerf-tests | xz -T0 -6 > "$out.tmp"
mv "$out.tmp" "$out"
echo "package-tests: $(ls "$pkg" | grep -vc -e '^lib$' -e '^layers$' -e '^msnerf$' -e '\.sh$' -e '^BUILT_AT$') test binaries -> $out ($(du -h "$out" | cut -f1))"
