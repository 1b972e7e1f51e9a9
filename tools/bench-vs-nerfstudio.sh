#!/usr/bin/env bash
# msnerf vs nerfstudio, side by side (issue 22): times nerfstudio 1.1.5's own nerfacto training step on the CPU
# (tools/bench/nerfstudio_nerfacto_step.py: torch implementation, nerfacto's method config, the Trainer's iteration)
# and msnerf's nerfacto at 3 bands (`msnerf bench train`) on the same synthetic scene (16 ring cameras 256x192,
# random pixels, random RGB targets), the same batch size and the same step counter (past the proposal warm-up, two
# untimed steps each), on this machine; prints the machine, msnerf's device, both rays/s and the ratio.
#   usage: tools/bench-vs-nerfstudio.sh [--install] [--steps N] [--rays R] [--out FILE.json]   (defaults: 6, 4096)
#   --install  creates the throwaway venv NS_VENV if needed and installs torch 2.15.0 (PyPI's wheel with its CUDA
#              libraries: ~3 GB download, ~6 GB on disk, ~10 minutes; set TORCH_INDEX_URL to take torch from another
#              index, e.g. a CPU-only one), nerfstudio 1.1.5 without its dependencies and the pinned packages below.
#   --out      writes both JSONs, the machine and the ratio to FILE.json.
#   NS_VENV (default /tmp/ns-venv); MSNERF_BIN (default target/release/msnerf, built with cargo if missing);
#   MSNERF_DEVICE picks msnerf's Vulkan device; NS_THREADS nerfstudio's torch threads (default: every core);
#   NS_PYTHON the Python (3.10+) --install makes the venv with (default python3).
# Steps: a multiple of 6 gives both sides the same share of proposal-update steps (one in 6 past the warm-up).
set -euo pipefail
cd "$(dirname "$0")/.."
me=bench-vs-nerfstudio
die() { echo "$me: $*" >&2; exit 2; }
install=0; steps=6; rays=4096; out=
while [ $# -gt 0 ]; do
  case $1 in
    --install) install=1 ;;
    --steps|--rays|--out)
      [ $# -ge 2 ] || die "$1 needs a value"
      case $1 in --steps) steps=$2 ;; --rays) rays=$2 ;; --out) out=$2 ;; esac
      shift ;;
    --steps=*) steps=${1#*=} ;;
    --rays=*) rays=${1#*=} ;;
    --out=*) out=${1#*=} ;;
    -h|--help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) die "unknown flag: $1 (usage: tools/bench-vs-nerfstudio.sh [--install] [--steps N] [--rays R] [--out FILE.json])" ;;
  esac
  shift
done
[[ $steps =~ ^[1-9][0-9]*$ ]] || die "--steps needs a positive integer, got '$steps'"
[[ $rays =~ ^[1-9][0-9]*$ ]] || die "--rays needs a positive integer, got '$rays'"
[ -z "$out" ] || [ -d "$(dirname "$out")" ] || die "--out: no such folder: $(dirname "$out")"
venv=${NS_VENV:-/tmp/ns-venv}
bin=${MSNERF_BIN:-target/release/msnerf}
py=$venv/bin/python
# What the step script imports, nerfstudio installed with --no-deps (pinned: the versions the tool was written with).
ns_pkgs=(numpy==2.4.6 jaxtyping==0.3.11 rich==15.0.0 nerfacc==0.5.3 tyro==1.0.17 docstring-parser==0.18.0
  opencv-python-headless==5.0.0.93 tensorboard==2.21.0 protobuf==7.36.2 absl-py==2.5.1 matplotlib==3.11.2
  packaging==26.4 pillow==13.0.0 pyparsing==3.3.3 cycler==0.12.1 python-dateutil==4.0.0 kiwisolver==1.5.1
  fonttools==4.68.0 torchmetrics==1.9.0 lightning-utilities==0.15.3 viser==1.1.1 msgspec==0.22.0 websockets==17.4
  zstandard==0.25.0)
check='import torch, torchmetrics.image.lpip, nerfstudio.models.nerfacto, nerfstudio.engine.optimizers, nerfstudio.data.pixel_samplers'

if [ "$install" = 1 ]; then
  [ -x "$py" ] || "${NS_PYTHON:-python3}" -m venv "$venv"
  "$venv/bin/pip" install --upgrade pip
  if [ -n "${TORCH_INDEX_URL:-}" ]; then
    "$venv/bin/pip" install --index-url "$TORCH_INDEX_URL" torch==2.15.0
  else
    "$venv/bin/pip" install torch==2.15.0
  fi
  "$venv/bin/pip" install --no-deps nerfstudio==1.1.5 "${ns_pkgs[@]}"
fi
if [ ! -x "$py" ]; then
  die "no Python venv at NS_VENV=$venv: pass --install to create it (torch 2.15.0 with its CUDA libraries, ~3 GB" \
    "download, ~6 GB on disk, about 10 minutes; nerfstudio 1.1.5 and ~20 small packages)"
fi
if ! err=$("$py" -W ignore -c "$check" 2>&1 >/dev/null); then
  echo "$err" | tail -n 3 >&2
  die "the venv at NS_VENV=$venv cannot import nerfstudio's nerfacto (above): pass --install to install what is" \
    "missing (torch 2.15.0 is ~3 GB if absent; the rest ~100 MB)"
fi
if [ ! -x "$bin" ]; then
  [ -z "${MSNERF_BIN:-}" ] || die "MSNERF_BIN=$bin is not an executable"
  echo "$me: $bin missing: cargo build --release" >&2
  cargo build --release
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cpu=$(grep -m1 '^model name' /proc/cpuinfo | sed 's/^[^:]*: *//' || true)
cores=$(nproc)
echo "$me: nerfstudio nerfacto, $rays rays, $steps timed steps ($venv)" >&2
ns_args=(--rays "$rays" --steps "$steps" --warmup 2)
[ -z "${NS_THREADS:-}" ] || ns_args+=(--threads "$NS_THREADS")
"$py" tools/bench/nerfstudio_nerfacto_step.py "${ns_args[@]}" > "$work/nerfstudio.json"
echo "$me: msnerf nerfacto, 3 bands, $rays rays, $steps timed steps ($bin)" >&2
"$bin" bench train --models nerfacto --bands 3 --rays-per-batch "$rays" --steps "$steps" --json > "$work/msnerf.json"
# msnerf's JSON does not name the device: the one `msnerf devices` marks as selected (MSNERF_DEVICE applies to both).
"$bin" devices > "$work/devices.txt" 2>/dev/null || true
device=$(awk '/<- selected/ {sel = 1; sub(/^\[[0-9]+\] */, ""); sub(/ *<- selected$/, ""); name = $0; next}
  sel && $1 == "driver" {sub(/^ *driver */, ""); name = name ", " $0; exit}
  sel && /^\[/ {exit}
  END {print name}' "$work/devices.txt")
[ -n "$device" ] || device=$(head -n 1 "$work/devices.txt")

CPU=$cpu CORES=$cores DEVICE=$device OUT=$out WORK=$work "$py" - <<'EOF'
import json, os
ns = json.load(open(os.path.join(os.environ["WORK"], "nerfstudio.json")))
ms_all = json.load(open(os.path.join(os.environ["WORK"], "msnerf.json")))
ms = ms_all[0] if isinstance(ms_all, list) else ms_all
ratio = ms["rays_per_s"] / ns["rays_per_s"]
machine = {"cpu": os.environ["CPU"], "cores": int(os.environ["CORES"])}
rows = [
    ("nerfstudio %s nerfacto (torch %s, CPU, %d threads)" % (ns["nerfstudio"], ns["torch"], ns["threads"]), ns),
    ("msnerf nerfacto, 3 bands (Vulkan, %d steps in flight)" % ms["steps_in_flight"], ms),
]
print("machine: %s, %d cores" % (machine["cpu"], machine["cores"]))
print("msnerf device: %s" % os.environ["DEVICE"])
print("%-62s %6s %9s %9s %6s %6s %8s" % ("", "rays", "ms/step", "rays/s", "steps", "from", "updates"))
for name, r in rows:
    print("%-62s %6d %9.1f %9.0f %6d %6d %8d" % (name, r["rays_per_batch"], r["ms_per_step"], r["rays_per_s"],
          r["steps"], r["first_step"], r["proposal_update_steps"]))
print("ratio msnerf / nerfstudio (rays/s): %.2fx" % ratio)
out = os.environ["OUT"]
if out:
    doc = {"machine": machine, "msnerf_device": os.environ["DEVICE"], "ratio_msnerf_over_nerfstudio": ratio,
           "nerfstudio": ns, "msnerf": ms_all}
    tmp = out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, out)
    print("written: %s" % out)
EOF
