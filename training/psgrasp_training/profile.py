"""``python -m psgrasp_training profile``: where the time of a training step goes.

Runs a few training steps of a config on a dataset exactly as :func:`train.fit` does (same scene
order, augmentation, loss, Adam step; no run directory, nothing saved) and times each phase:
scene loading, the U-Net forward pass, the label loss, contact points, grasp targets, feature
sampling, the MLP, the grasp loss, the backward pass and the optimiser step. Prints a Markdown
table of mean milliseconds per phase and the steps and scenes per second.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import torch

from .config import Config
from .data import SceneDataset
from .model import GraspNet
from .train import apply_dataset_geometry, scene_for_step, setup_torch, training_step

#: Steps run before timing (allocator and thread-pool warm-up).
WARMUP_STEPS = 2


class PhaseTimer:
    """Accumulates the wall time between successive marks under the phase names given."""

    def __init__(self) -> None:
        self.totals: dict[str, float] = defaultdict(float)
        self.order: list[str] = []
        self.last = time.perf_counter()

    def start(self) -> None:
        """Start a step: the next mark measures from now."""
        self.last = time.perf_counter()

    def mark(self, phase: str) -> None:
        """End `phase` now."""
        now = time.perf_counter()
        if phase not in self.totals:
            self.order.append(phase)
        self.totals[phase] += now - self.last
        self.last = now


def profile_steps(cfg: Config, data: Path, steps: int, start_step: int = 0, log=print) -> dict[str, float]:
    """Mean seconds per phase over `steps` training steps from `start_step` (after a warm-up)."""
    device = setup_torch(cfg)
    ds = SceneDataset(data, cfg)
    apply_dataset_geometry(cfg, ds.info)
    torch.manual_seed(cfg.seed)
    net = GraspNet(cfg).to(device).train()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.train.lr)
    timer = PhaseTimer()
    with_mlp = start_step >= cfg.train.mlp_warmup_iterations
    t_all = 0.0
    for k in range(WARMUP_STEPS + steps):
        if k == WARMUP_STEPS:
            timer = PhaseTimer()
            t_all = time.perf_counter()
        timer.start()
        scene, g = scene_for_step(ds, cfg, start_step + k)
        timer.mark("scene load + flip")
        out = training_step(net, scene, cfg, g, device, with_mlp, mark=timer.mark)
        opt.zero_grad(set_to_none=True)
        out["loss"].backward()
        timer.mark("backward")
        opt.step()
        timer.mark("optimiser step")
    wall = time.perf_counter() - t_all
    means = {p: timer.totals[p] / steps for p in timer.order}
    log(f"{steps} steps from step {start_step} ({'with' if with_mlp else 'without'} the MLP), "
        f"{torch.get_num_threads()} thread(s), device {device}: {steps / wall:.3f} steps/s, "
        f"{steps / wall:.3f} scenes/s\n")
    log("| phase | ms per step | share |\n|---|---:|---:|")
    total = sum(means.values())
    for p, s in means.items():
        log(f"| {p} | {1000 * s:.1f} | {100 * s / total:.1f} % |")
    log(f"| total | {1000 * total:.1f} | 100 % |")
    return means
