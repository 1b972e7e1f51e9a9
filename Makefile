# Single entry point. `make test` and `make demo` install what is missing first (tools/setup-debian.sh).
CARGO ?= cargo
# The suite runs with the Khronos validation layer and fails on any message it prints.
export MSNERF_REQUIRE_VALIDATION ?= 1
# Fresh GPU buffers hold NaN bits, so a read of memory nobody wrote fails a test on lavapipe as it would on NVIDIA.
export MSNERF_POISON_BUFFERS ?= 1

# Where `make install` puts the binary.
PREFIX ?= $(HOME)/.local

.PHONY: setup test test-fast lint build install cli-reference terrain-report demo devices bench clean accuracy-report accuracy-report-5min mlp-precision-report geometry-report geometry-sweep background-seeds survey-report import-bench rig-parallax test-slurm scale-acceptance flight-acceptance flight-acceptance-gcp flight-acceptance-paper

setup:
	@bash tools/setup-debian.sh

lint: setup
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --all-targets --release -- -D warnings

test: lint
	$(CARGO) test --release

# The edit-compile loop's tier (no lint, no COLMAP, no training runs): the library's unit tests and the kernel,
# stability and outputs binaries. `make test` stays what CI runs.
test-fast: setup
	$(CARGO) test --release --lib --test kernels --test stability --test outputs

build: setup
	$(CARGO) build --release

devices: build
	./target/release/msnerf devices

demo: build
	./target/release/msnerf demo

# `msnerf` on the PATH: the release binary into $(PREFIX)/bin (default ~/.local/bin, on Debian's PATH at the next login).
install: build
	install -D -m 755 target/release/msnerf $(PREFIX)/bin/msnerf
	@case ":$$PATH:" in *":$(PREFIX)/bin:"*) echo "msnerf installed in $(PREFIX)/bin";; \
	  *) echo "msnerf installed in $(PREFIX)/bin, which is not on your PATH: add it (export PATH=\"$(PREFIX)/bin:\$$PATH\")";; esac

# The CLI reference (docs/reference/cli.md) written again from the binary's help; a test fails when it is stale.
cli-reference:
	MSNERF_UPDATE_REFERENCE=1 cargo test --release --lib cli_reference

# docs/results/terrain.md: DTM, CHM and trees on a ten-minute campus run against the simulator's truth (~15 min).
terrain-report: build
	bash tools/terrain-report.sh terrain-report-output 600

# docs/accuracy-vs-time.md and its plots: the configs/sweeps/accuracy-report.yaml sweep on the built-in campus scene
# (~20 min on 2 cores with lavapipe). Resumable: rerunning skips the cells already in accuracy-report-output/.
accuracy-report: build
	./target/release/msnerf sweep --builtin-scene campus --grid configs/sweeps/accuracy-report.yaml \
		--out accuracy-report-output --report docs/accuracy-vs-time.md

# docs/accuracy-vs-time-5min.md: three configurations and a seed repeat for 5 minutes each (~22 min on 2 cores with lavapipe).
accuracy-report-5min: build
	./target/release/msnerf sweep --builtin-scene campus --grid configs/sweeps/five-minutes.yaml \
		--out accuracy-report-5min-output --report docs/accuracy-vs-time-5min.md

# docs/mlp-precision.md: fp32 against fp16 hidden activations and a seed repeat, 90 s each (~6 min on 2 cores with lavapipe).
mlp-precision-report: build
	./target/release/msnerf sweep --builtin-scene campus --grid configs/sweeps/mlp-precision.yaml \
		--out mlp-precision-output --report docs/mlp-precision.md

# docs/geometry-vs-time.md: depth and cloud accuracy against time, poses against aerial normalisation, a seed repeat (~18 min).
geometry-sweep: build
	./target/release/msnerf sweep --builtin-scene campus --grid configs/sweeps/geometry.yaml \
		--out geometry-sweep-output --report docs/geometry-vs-time.md

# docs/geometry/: the raw numbers behind docs/geometry.md's ten-minute table (campus, demo profile, 600 s, images only and with SfM points; ~26 min).
geometry-report: build
	bash tools/geometry-report.sh geometry-report-output 600

# docs/geometry.md's "A transparent field": last_sample against random background over four seeds, 4,000 steps each (~28 min).
background-seeds: build
	bash tools/background-seeds.sh background-seeds-output

# docs/geometry.md's survey products (DSM, true ortho) from geometry-report's two campus runs (~2 min).
survey-report: build
	bash tools/survey-report.sh geometry-report-output

clean:
	$(CARGO) clean

# docs/results/log/bench-import-<date>.json: raw rig import speed on the real RedEdge flight capture, replicated 16 times (~2 min).
import-bench: build
	bash tools/import-bench.sh

# docs/results/log/rig-parallax-<date>.json: rig-aware training against homography-warped (per frame and shared) and naive bands on the simulated
# rig-low flight, 200 s of training each (~15 min on 2 cores with lavapipe; docs/radiometry.md quotes it).
rig-parallax: build
	bash tools/rig-parallax.sh rig-parallax-output 200

# issue 23's Slurm path on a real one-node cluster on this machine (installs slurm-wlm and munge as root; ~5 min on 2
# cores with lavapipe): partition, sbatch of the job array, a requeued task resuming, the merged cloud. Not part of
# `make test` (it starts daemons as root); docs/scale.md records its last run.
test-slurm: build
	bash tools/test-slurm.sh

# issue 23's acceptance (docs/results/log/scale-acceptance-<date>.json, quoted in docs/scale.md): campus trained as one run and as
# 2x2 blocks at the same total steps, both clouds and DSMs against the truth (~20 min on 2 cores with lavapipe).
scale-acceptance: build
	bash tools/scale-acceptance.sh scale-acceptance-output 8000

# Issue 50's acceptance: a raw flight simulated as a RedEdge-MX card, `msnerf process` from its card, the same flight
# written directly by the simulator, every product against the truth (docs/results/flight.md; ~15 min on 2 cores).
flight-acceptance: build
	bash tools/flight-acceptance.sh ci flight-acceptance-ci 300

# The same with five ground control points (OpenDroneMap's gcp_list.txt): the products judged as delivered.
flight-acceptance-gcp: build
	GCP=5 bash tools/flight-acceptance.sh ci flight-acceptance-ci-gcp 300

# The paper's size: 300 captures of 1280x960 (hours on a CPU: the stages' time and host memory are the figures).
flight-acceptance-paper: build
	bash tools/flight-acceptance.sh paper flight-acceptance-paper 600
