"""Run directories and checkpoints.

A run directory holds ``config.json`` (the resolved configuration), ``dataset.json`` (what the run
trains on), ``log.csv``, ``validation.json`` and ``checkpoints/step_NNNNNNN.pt`` + ``latest.pt``.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from .config import Config, config_from_dict

CHECKPOINT_FORMAT = "psgrasp-training-checkpoint"


class RunError(RuntimeError):
    """A run directory or checkpoint is missing or unusable (the message says which file)."""


@dataclass
class DatasetInfo:
    """Geometry and provenance of the training data (or the config's grid for an untrained model)."""

    path: str = ""
    manifest_sha256: str = ""
    dims: list[int] = field(default_factory=lambda: [64, 64, 64])
    voxel_size_m: float = 0.009
    max_opening_m: float = 0.08
    approach_depth_m: float = 0.0445
    train_scenes: int = 0
    val_scenes: int = 0

    @staticmethod
    def from_config(cfg: Config) -> "DatasetInfo":
        """Geometry from the config (no dataset)."""
        g = cfg.grid
        return DatasetInfo(dims=list(g.dims), voxel_size_m=g.voxel_size_m, max_opening_m=g.max_opening_m,
                           approach_depth_m=g.approach_depth_m)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file and rename into place."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_json(path: Path, value: Any) -> None:
    """Atomically write pretty JSON."""
    atomic_write_bytes(path, (json.dumps(value, indent=2) + "\n").encode())


def save_checkpoint(run_dir: Path, step: int, cfg: Config, model: torch.nn.Module, dataset: DatasetInfo,
                    optimizer: torch.optim.Optimizer | None = None, validation: dict | None = None,
                    elapsed_s: float = 0.0) -> Path:
    """Save ``checkpoints/step_NNNNNNN.pt`` and ``latest.pt`` (atomic)."""
    ckpt_dir = run_dir / "checkpoints"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    state = {
        "format": CHECKPOINT_FORMAT,
        "step": step,
        "config": cfg.to_dict(),
        "dataset": asdict(dataset),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "validation": validation,
        "elapsed_s": elapsed_s,
    }
    path = ckpt_dir / f"step_{step:07d}.pt"
    for target in (path, ckpt_dir / "latest.pt"):
        tmp = target.with_name(f".{target.name}.tmp-{os.getpid()}")
        torch.save(state, tmp)
        os.replace(tmp, target)
    return path


def load_checkpoint(run_dir: Path, name: str = "latest.pt") -> dict[str, Any]:
    """Load a checkpoint of a run directory; config and dataset are returned as objects."""
    return load_checkpoint_file(Path(run_dir) / "checkpoints" / name)


def load_checkpoint_file(path: Path) -> dict[str, Any]:
    """Load one checkpoint file; config and dataset are returned as objects."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"no checkpoint {path} (train or init the run first)")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unpickling failure means a corrupt file
        raise RunError(f"cannot read checkpoint {path}: {e}") from e
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise RunError(f"{path} is not a psgrasp training checkpoint")
    state["config"] = config_from_dict(state["config"])
    state["dataset"] = DatasetInfo(**state["dataset"])
    return state
