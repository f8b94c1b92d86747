"""Training loop (placeholder: init only)."""

from __future__ import annotations

from pathlib import Path

import torch

from .checkpoint import DatasetInfo, save_checkpoint, write_json
from .config import Config
from .data import SceneDataset
from .model import GraspNet


def apply_dataset_geometry(cfg: Config, info: DatasetInfo) -> None:
    """Make the config's grid/gripper geometry that of the dataset."""
    cfg.grid.dims = list(info.dims)
    cfg.grid.voxel_size_m = info.voxel_size_m
    cfg.grid.max_opening_m = info.max_opening_m
    cfg.grid.approach_depth_m = info.approach_depth_m
    cfg.validate()


def init_run(cfg: Config, run_dir: Path, data: Path | None = None) -> None:
    """Create a run directory with an untrained model (step 0)."""
    run_dir = Path(run_dir)
    if data is not None:
        info = SceneDataset(data, cfg).info
        apply_dataset_geometry(cfg, info)
    else:
        info = DatasetInfo.from_config(cfg)
    torch.manual_seed(cfg.seed)
    net = GraspNet(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", cfg.to_dict())
    save_checkpoint(run_dir, 0, cfg, net, info)
