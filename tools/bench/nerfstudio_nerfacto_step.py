#!/usr/bin/env python3
"""Times nerfstudio's own nerfacto training step on the CPU, on the synthetic setup of `msnerf bench train`
(src/bench/train.rs), and prints one JSON object. The nerfstudio half of tools/bench-vs-nerfstudio.sh (issue 22).

Written against nerfstudio 1.1.5 and torch 2.15.0 (PyPI wheel, run on the CPU), Python 3.11; the venv the shell
script's --install makes. Run: NS_VENV/bin/python tools/bench/nerfstudio_nerfacto_step.py [--rays 4096] [--steps 5]

The scene (as msnerf's bench): 16 pinhole cameras 256x192, fx = fy = 200, cx = 128, cy = 96, on a ring of radius 0.9
at height 0.4 looking at the origin (OpenGL camera-to-world, the camera looks along -z, nerfstudio's convention too),
random RGB "images" in [0, 1). Nothing here re-implements nerfstudio; every piece of the step is nerfstudio's code:

  model       NerfactoModelConfig as method_configs["nerfacto"] sets it (eval_num_rays_per_chunk 1 << 15,
              average_init_density 0.01, CameraOptimizerConfig(mode="SO3xR3"); every other field its default),
              plus implementation="torch" (no tiny-cuda-nn on the CPU: nerfstudio's pure-torch hash grid and MLPs).
              SceneBox [-1, 1]^3 (the nerfstudio dataparser's at scene_scale 1; unused under scene contraction),
              num_train_data 16, built by ModelConfig.setup as VanillaPipeline does.
  optimizers  nerfstudio's Optimizers with method_configs["nerfacto"]'s dict: proposal_networks and fields Adam
              lr 1e-2 eps 1e-15, camera_opt Adam lr 1e-3 eps 1e-15, ExponentialDecayScheduler (lr_final 1e-4 over
              200000 / 5000 steps). GradScaler(enabled=True) as the Trainer builds it (mixed_precision=True in the
              method config: torch disables the scaler when CUDA is unavailable); autocast off (the Trainer turns
              mixed precision off on the CPU); gradient accumulation 1 for every group.
  batch       ParallelDataManager's worker work, done inline: PixelSampler(num_rays_per_batch=R).sample() over the
              cached image batch {"image": 16x192x256x3, "image_idx"}, then RayGenerator(cameras)(indices), i.e.
              Cameras.generate_rays with camera_indices, so the appearance embedding and the camera optimizer see
              real camera indices. (nerfstudio runs this in a separate process, overlapped with the step; it is
              timed here, inside the step, as msnerf's batch sampling is; `batch_ms_per_step` reports its share.)
  one step    Trainer.train() and Trainer.train_iteration for step s: pipeline.train(); the callbacks at
              BEFORE_TRAIN_ITERATION (nerfacto's set_anneal); zero_grad of every group; batch; model(ray_bundle)
              (collider, camera-optimizer pose tweak, proposal sampler, field, renderers); get_metrics_dict (PSNR,
              distortion, camera-optimizer metrics); get_loss_dict with the batch dict; sum of the losses; backward;
              Optimizers.optimizer_scaler_step_some for every group; grad scaler update; scheduler_step_all; the
              callbacks at AFTER_TRAIN_ITERATION (ProposalNetworkSampler.step_cb).

The step counter starts at msnerf's steady state, max(proposal_warmup, proposal_weights_anneal_max_num_iters, 10) + 1
= 5001 by default (--first-step), so the anneal is 1 and the proposal networks are updated (with gradients) only when
the sampler's schedule says so: `_steps_since_update > update_sched(step)`, i.e. one step in 6 past the warm-up (the
same rule msnerf follows). Untimed warm-up steps (--warmup) run first; the very first always updates (the sampler's
own `_step < 10` rule, as after a checkpoint resume). The schedulers start at step 0 (their learning rate does not
change the work).

Not part of any training step, patched: torchmetrics' LearnedPerceptualImagePatchSimilarity, which nerfacto builds
in populate_modules for its eval images only, would download AlexNet and LPIPS weights. It is replaced, before the
model is built, by a stand-in module that raises if called. Nothing that runs in the training step is patched.

Output (stdout, one JSON object): rays_per_s, ms_per_step, batch_ms_per_step, steps, first_step, warmup,
proposal_update_steps (timed steps that updated the proposals), rays_per_batch, torch / nerfstudio versions,
threads (torch.get_num_threads()), interop threads, the seed and the per-step times. Everything else goes to stderr.
"""
import argparse
import contextlib
import functools
import json
import os
import platform
import random
import sys
import time
import warnings


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rays", type=int, default=4096, help="rays per batch (default 4096)")
    p.add_argument("--steps", type=int, default=5, help="timed steps (default 5)")
    p.add_argument("--warmup", type=int, default=2, help="untimed steps first (default 2, as msnerf's bench)")
    p.add_argument("--first-step", type=int, default=None, help="step counter of the first untimed step "
                   "(default: the steady state, max(proposal_warmup, anneal iterations, 10) + 1)")
    p.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: os.cpu_count())")
    p.add_argument("--seed", type=int, default=7)
    a = p.parse_args()
    for name in ("rays", "steps"):
        if getattr(a, name) < 1:
            p.error(f"--{name} must be >= 1")
    if a.warmup < 0:
        p.error("--warmup must be >= 0")
    return a


def ring_cameras(n, torch):
    """msnerf's ring_cameras (src/bench/train.rs), as a [n, 3, 4] camera-to-world tensor."""
    c2w = torch.zeros(n, 3, 4)
    for i in range(n):
        a = i * 2.0 * torch.pi / n
        pos = torch.tensor([0.9 * torch.cos(torch.tensor(a)).item(), 0.9 * torch.sin(torch.tensor(a)).item(), 0.4])
        z = pos / pos.norm()
        x = torch.tensor([-z[1].item(), z[0].item(), 0.0])
        x = x / x.norm()
        y = torch.linalg.cross(z, x)
        c2w[i, :, 0], c2w[i, :, 1], c2w[i, :, 2], c2w[i, :, 3] = x, y, z, pos
    return c2w


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main():
    a = parse_args()
    real_stdout = sys.stdout
    warnings.filterwarnings("ignore")
    with contextlib.redirect_stdout(sys.stderr):  # nerfstudio's CONSOLE and friends print to stdout
        result = run(a)
    real_stdout.write(json.dumps(result, indent=2) + "\n")


def run(a):
    import numpy as np
    import torch

    threads = a.threads or os.cpu_count() or 1
    torch.set_num_threads(threads)
    random.seed(a.seed)
    np.random.seed(a.seed)
    torch.manual_seed(a.seed)

    import torchmetrics.image.lpip as lpip_mod

    class _NoLpips(torch.nn.Module):
        """Stand-in for LPIPS (eval-only metric; the real one downloads weights at construction)."""

        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, *args, **kwargs):
            raise RuntimeError("LPIPS is stubbed out in this benchmark (eval metric, not part of a training step)")

    lpip_mod.LearnedPerceptualImagePatchSimilarity = _NoLpips

    from torch.cuda.amp.grad_scaler import GradScaler

    import nerfstudio
    from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig
    from nerfstudio.cameras.cameras import Cameras, CameraType
    from nerfstudio.data.pixel_samplers import PixelSamplerConfig
    from nerfstudio.data.scene_box import SceneBox
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
    from nerfstudio.engine.optimizers import AdamOptimizerConfig, Optimizers
    from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig
    from nerfstudio.model_components.ray_generators import RayGenerator
    from nerfstudio.models.nerfacto import NerfactoModelConfig

    try:
        from importlib.metadata import version as pkg_version

        ns_version = pkg_version("nerfstudio")
    except Exception:  # pragma: no cover
        ns_version = getattr(nerfstudio, "__version__", "unknown")

    device = "cpu"
    n_cams, width, height = 16, 256, 192
    cameras = Cameras(
        camera_to_worlds=ring_cameras(n_cams, torch),
        fx=200.0,
        fy=200.0,
        cx=128.0,
        cy=96.0,
        width=width,
        height=height,
        camera_type=CameraType.PERSPECTIVE,
    )
    # The cached training images of the ParallelDataManager's worker (float32 RGB in [0, 1)).
    image_batch = {"image": torch.rand(n_cams, height, width, 3), "image_idx": torch.arange(n_cams)}
    pixel_sampler = PixelSamplerConfig().setup(is_equirectangular=False, num_rays_per_batch=a.rays,
                                               fisheye_crop_radius=None)
    ray_generator = RayGenerator(cameras)

    # method_configs["nerfacto"] (nerfstudio/configs/method_configs.py), implementation="torch" for the CPU.
    model_config = NerfactoModelConfig(
        eval_num_rays_per_chunk=1 << 15,
        average_init_density=0.01,
        camera_optimizer=CameraOptimizerConfig(mode="SO3xR3"),
        implementation="torch",
    )
    optimizer_config = {
        "proposal_networks": {
            "optimizer": AdamOptimizerConfig(lr=1e-2, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=0.0001, max_steps=200000),
        },
        "fields": {
            "optimizer": AdamOptimizerConfig(lr=1e-2, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=0.0001, max_steps=200000),
        },
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-3, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(lr_final=1e-4, max_steps=5000),
        },
    }
    mixed_precision = False  # method config True; the Trainer turns it off on the CPU
    grad_scaler = GradScaler(enabled=True)  # Trainer: use_grad_scaler = config.mixed_precision (True) or ...
    scene_box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    model = model_config.setup(scene_box=scene_box, num_train_data=n_cams, metadata={}, device=device,
                               grad_scaler=grad_scaler, seed_points=None)
    model.to(device)
    optimizers = Optimizers(optimizer_config, model.get_param_groups())
    callbacks = model.get_training_callbacks(
        TrainingCallbackAttributes(optimizers=optimizers, grad_scaler=grad_scaler, pipeline=None, trainer=None)
    )  # VanillaPipeline: the datamanager's callbacks ([] for nerfstudio's datamanagers) + the model's
    sampler = model.proposal_sampler
    mc = model.config
    first = a.first_step
    if first is None:
        first = max(mc.proposal_warmup, mc.proposal_weights_anneal_max_num_iters, 10) + 1

    def next_train():
        """ParallelDataManager: the worker's pixel sampling and ray generation, then next_train's .to(device)."""
        batch = pixel_sampler.sample(image_batch)
        ray_bundle = ray_generator(batch["indices"])
        return ray_bundle.to(device), batch

    batch_s = [0.0]

    def train_iteration(step):
        """Trainer.train_iteration (gradient accumulation 1 for every group)."""
        optimizers.zero_grad_some(list(optimizers.parameters.keys()))
        with torch.autocast(device_type="cpu", enabled=mixed_precision):
            tb = time.perf_counter()
            ray_bundle, batch = next_train()
            batch_s[0] += time.perf_counter() - tb
            # VanillaPipeline.get_train_loss_dict
            model_outputs = model(ray_bundle)
            metrics_dict = model.get_metrics_dict(model_outputs, batch)
            loss_dict = model.get_loss_dict(model_outputs, batch, metrics_dict)
            loss = functools.reduce(torch.add, loss_dict.values())
        grad_scaler.scale(loss).backward()
        optimizers.optimizer_scaler_step_some(grad_scaler, list(optimizers.parameters.keys()))
        scale = grad_scaler.get_scale()
        grad_scaler.update()
        if scale <= grad_scaler.get_scale():
            optimizers.scheduler_step_all(step)
        return loss, loss_dict

    def one_step(step):
        """One iteration of Trainer.train's loop (without the logging, eval and checkpoint work after it)."""
        model.train()  # pipeline.train()
        for cb in callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
        loss, loss_dict = train_iteration(step)
        for cb in callbacks:
            cb.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
        return loss

    from nerfstudio.utils import writer

    step = first
    print(f"nerfstudio {ns_version}, torch {torch.__version__}, {torch.get_num_threads()} threads: "
          f"{a.warmup} warm-up steps from step {first}, then {a.steps} timed steps of {a.rays} rays",
          file=sys.stderr)
    t0 = time.perf_counter()
    for _ in range(a.warmup):
        loss = one_step(step)
        step += 1
    warm_s = time.perf_counter() - t0
    writer.EVENT_STORAGE.clear()  # the Trainer's write_out_storage after every step (no writers configured)
    first_timed = step
    batch_s[0] = 0.0
    times, updates, losses = [], 0, []
    for _ in range(a.steps):
        ts = time.perf_counter()
        loss = one_step(step)
        times.append(time.perf_counter() - ts)
        # generate_ray_samples zeroes _steps_since_update when it updates, step_cb then adds one.
        updates += int(sampler._steps_since_update == 1)
        losses.append(float(loss.detach()))
        writer.EVENT_STORAGE.clear()
        step += 1
    total = sum(times)
    ms = total * 1e3 / a.steps
    return {
        "tool": "nerfstudio nerfacto training step (tools/bench/nerfstudio_nerfacto_step.py)",
        "model": "nerfacto",
        "implementation": mc.implementation,
        "device": "cpu",
        "cpu": cpu_model(),
        "rays_per_batch": a.rays,
        "steps": a.steps,
        "warmup": a.warmup,
        "warmup_s": warm_s,
        "first_step": first_timed,
        "ms_per_step": ms,
        "rays_per_s": a.rays / (ms / 1e3),
        "batch_ms_per_step": batch_s[0] * 1e3 / a.steps,
        "ms_per_step_each": [t * 1e3 for t in times],
        "proposal_update_steps": updates,
        "proposal_update_every": mc.proposal_update_every,
        "num_proposal_samples_per_ray": list(mc.num_proposal_samples_per_ray),
        "num_nerf_samples_per_ray": mc.num_nerf_samples_per_ray,
        "camera_optimizer": mc.camera_optimizer.mode,
        "grad_scaler_enabled": grad_scaler.is_enabled(),
        "losses": losses,
        "threads": torch.get_num_threads(),
        "interop_threads": torch.get_num_interop_threads(),
        "cpu_count": os.cpu_count(),
        "seed": a.seed,
        "torch": torch.__version__,
        "nerfstudio": ns_version,
        "python": platform.python_version(),
    }


if __name__ == "__main__":
    main()
