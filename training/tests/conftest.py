"""Shared fixtures: one torch thread, a small analytic dataset, a tiny config."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from psgrasp_training.config import config_from_dict  # noqa: E402
from synthetic import write_dataset  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(scope="session")
def box_dataset(tmp_path_factory) -> Path:
    """Three analytic box scenes (16³ voxels)."""
    return write_dataset(tmp_path_factory.mktemp("boxes"), scenes=3, seed=7)


def tiny_config(**train):
    """A tiny config for 16³ grids; `train` overrides [train] fields."""
    t = {"iterations": 10, "mlp_warmup_iterations": 3, "checkpoint_every": 5, "log_every": 5, "threads": 1}
    t.update(train)
    return config_from_dict({
        "seed": 3,
        "model": {"levels": 2, "base_channels": 4, "mlp_hidden": [16, 16]},
        "grid": {"dims": [16, 16, 16]},
        "data": {"val_scenes": 1, "cache": True},
        "contacts": {"max_points": 64, "predicted_points": 8},
        "train": t,
    })


@pytest.fixture
def tiny_cfg():
    """Factory for tiny configs."""
    return tiny_config
