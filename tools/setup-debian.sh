#!/usr/bin/env bash
# Installs what msnerf needs on Debian 12 (and Ubuntu 22.04+), the packages msnerf's build, tests and tools use.
#   - Vulkan loader, Mesa lavapipe (the CPU Vulkan driver CI uses), Khronos validation layers, vulkaninfo
#   - Debian's shaderc / glslang / SPIRV-Tools static libraries, which build.rs links (tools/shaderc-link)
#   - gdal-bin: `gdalinfo`, `gdalsrsinfo`, `gdaltransform`, which the tests run to check msnerf's GeoTIFFs, LAS CRS
#     records and projections against GDAL/PROJ; python3-gdal: GDAL's Cloud-Optimized GeoTIFF validator, which
#     the survey-export tests run on the DSM and orthomosaic
#   - colmap (3.8, no CUDA): `msnerf sfm` runs it, and tests/data/sfm_colmap.rs runs that
# Runs apt-get as root or through sudo; otherwise prints the command to run. Idempotent: a second run does nothing.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf 'setup: %s\n' "$*"; }
die() { printf 'setup: ERROR: %s\n' "$*" >&2; exit 1; }

# --- Rust ------------------------------------------------------------------------------------------
if ! command -v cargo >/dev/null 2>&1; then
  die "cargo not found. Install Rust 1.85 or newer with rustup (https://rustup.rs):
    curl --proto '=https' --tlsv1.2 -sSf https://sh.rustup.rs | sh -s -- -y && . \"\$HOME/.cargo/env\"
  (Debian's own rustc package is too old.) Then run this command again."
fi
for comp in rustfmt clippy; do
  if ! cargo "${comp/rustfmt/fmt}" --version >/dev/null 2>&1; then
    if command -v rustup >/dev/null 2>&1; then say "adding rust component $comp"; rustup component add "$comp";
    else die "cargo $comp is missing: install it with 'rustup component add $comp'"; fi
  fi
done

# --- System packages -------------------------------------------------------------------------------
PKGS=(libvulkan1 mesa-vulkan-drivers vulkan-validationlayers vulkan-tools libshaderc-dev glslang-dev spirv-tools binutils g++ gdal-bin python3-gdal colmap)
if command -v dpkg-query >/dev/null 2>&1; then
  missing=()
  for p in "${PKGS[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if ((${#missing[@]})); then
    if [ "$(id -u)" = 0 ]; then SUDO=(); elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO=(sudo);
    else die "missing packages: ${missing[*]}
  Run as root:  apt-get update && apt-get install -y ${missing[*]}
  then run this command again."; fi
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    "${SUDO[@]}" apt-get update -qq || die "apt-get update failed (no network or no apt sources?). Install by hand: ${missing[*]}"
    "${SUDO[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null \
      || die "apt-get install failed. Install by hand: ${missing[*]}"
  fi
else
  say "not a Debian-family system: install the Vulkan loader, a Vulkan driver (Mesa lavapipe works), the Khronos"
  say "validation layers and shaderc yourself, then set SHADERC_LIB_DIR to a complete shaderc (libshaderc_combined.a) or build with"
  say "'--features shaderc-from-source'."
fi

# --- A Vulkan device --------------------------------------------------------------------------------
icd=$(ls /usr/share/vulkan/icd.d/lvp_icd.*.json /etc/vulkan/icd.d/*.json /usr/share/vulkan/icd.d/nvidia_icd.json 2>/dev/null | head -n1 || true)
[ -n "$icd" ] || die "no Vulkan driver manifest found: install mesa-vulkan-drivers (lavapipe) or a GPU driver"
say "ready (Vulkan driver manifests present; shaderc, glslang and SPIRV-Tools static libraries installed)"
