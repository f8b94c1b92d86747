"""Training configuration: named fields with defaults, loaded from TOML.

Every tuned value of the training run is a field here; a TOML file only needs the fields it
changes. Unknown keys are refused (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Model variants (network contract ``variant`` field).
VARIANTS = ("8app", "1app-kappa", "1app-cosine", "vgn")


class ConfigError(ValueError):
    """A configuration file or value is invalid (the message names the field)."""


@dataclass
class ModelConfig:
    """Network architecture."""

    #: U-Net levels L (encoder feature grids enc0..enc{L-1}); the grid dims must be divisible by 2^(L-1).
    levels: int = 4
    #: Channels of level 0; level l has base·2^l channels.
    base_channels: int = 8
    #: Residual blocks per encoder and decoder level.
    blocks_per_level: int = 1
    #: Normalisation after each convolution: "batch" (folded into the convolutions at export) or "none".
    norm: str = "batch"
    #: Hidden layer widths of the MLP head.
    mlp_hidden: list[int] = field(default_factory=lambda: [256, 256, 128])
    #: Concentration scale κ0 (paper: 25); κ = min(max(κ0/(κ'+ε), κ0), 4κ0).
    kappa0: float = 25.0
    #: ε of the κ mapping.
    kappa_eps: float = 1e-6


@dataclass
class GridConfig:
    """Grid and gripper geometry used when no dataset metadata is at hand (untrained export)."""

    dims: list[int] = field(default_factory=lambda: [64, 64, 64])
    voxel_size_m: float = 0.009
    #: Maximum gripper opening (m); the width head is max_opening·sigmoid.
    max_opening_m: float = 0.08
    #: Distance from the TCP to the approach point, finger length − tip beyond TCP (m): 44.5 mm
    #: for the default gripper, the real Franka hand (54 − 9.5 mm).
    approach_depth_m: float = 0.0445


@dataclass
class DataConfig:
    """Dataset split, caching and augmentation."""

    #: Scenes with index % val_every == val_every − 1 are held out for validation (stable when the
    #: dataset grows); used when val_scenes < 0.
    val_every: int = 20
    #: If ≥ 0: hold out exactly the last val_scenes scenes by index instead.
    val_scenes: int = -1
    #: Use at most this many scenes of the dataset (0 = all), taken by index before the split.
    max_scenes: int = 0
    #: Keep loaded scenes in memory.
    cache: bool = False
    #: Random flips of the x and/or y axis (normals, labels and grasps transformed consistently).
    flip_augmentation: bool = True
    #: Train on crops of this many voxels per axis instead of the whole grid ([] = the whole grid):
    #: each step's crop holds a random ground-truth contact voxel (data.crop_scene). Validation,
    #: export and inference keep the whole grid (the network is fully convolutional). Each size
    #: must be a multiple of 2^(levels−1) and at most the grid's.
    crop: list[int] = field(default_factory=list)
    #: With data.crop: the share of steps whose crop is centred on a random observed-surface voxel
    #: (non-zero normal) instead of a ground-truth contact voxel, so that the contact head also
    #: sees surfaces without contacts (walls, floor, faces too wide to grasp) in the proportion
    #: the whole grid shows them. 0 (default): every crop holds a contact.
    crop_surface_share: float = 0.0


@dataclass
class ContactConfig:
    """Which points the MLP is trained on and how they are labelled."""

    #: "jittered-contact": a random true grasp contact inside the voxel plus a uniform jitter in a ball
    #: of radius jitter_m; "voxel-uniform": a uniform random point inside the voxel (the paper's rule).
    rule: str = "jittered-contact"
    #: Jitter radius of the jittered-contact rule (m); ≤ neighbour_radius_m guarantees ≥ 1 neighbour.
    jitter_m: float = 0.003
    #: At most this many ground-truth contact voxels (one point each) per step.
    max_points: int = 1024
    #: After the MLP warm-up, additionally up to this many points in predicted contact voxels that are
    #: not ground-truth contact voxels (they train quality → 0).
    predicted_points: int = 128
    #: P_contact threshold for those predicted voxels.
    predicted_probability: float = 0.5
    #: Additionally up to this many points by the paper's rule (one uniform point in each of as many
    #: random ground-truth contact voxels), labelled like every point by the true grasps within
    #: neighbour_radius_m: those off the surface have none and train quality → 0 where the sub-voxel
    #: centres of inference sample. 0 (default): none.
    uniform_points: int = 0
    #: Neighbour radius (m): true grasps whose contact lies within it label a point (paper: 3 mm).
    neighbour_radius_m: float = 0.003
    #: At most this many (nearest) neighbours per point (paper: 16).
    max_neighbours: int = 16


@dataclass
class LossConfig:
    """Loss weights (see README for the interpretation of the paper's values)."""

    #: φ_l: weight of the label (focal) loss.
    label: float = 1.0
    #: φ_g: weight of the grasp loss.
    grasp: float = 1.0
    #: Focal loss class weights in class order [empty, contact, gripper] (paper: 0.1, 10, 5).
    class_weights: list[float] = field(default_factory=lambda: [0.1, 10.0, 5.0])
    #: Focal loss γ.
    focal_gamma: float = 2.0
    #: η_b: baseline NLL (or 1 − cosine for the 1app-cosine variant).
    baseline: float = 1.0
    #: p: each neighbour label's term of the baseline NLL weighted by its antipodal quality^p
    #: (0 = the paper's plain mean over neighbours; > 0 pulls ν toward the most antipodal labels
    #: of a contact, whose baselines are drawn over a 40° friction cone).
    baseline_quality_power: float = 0.0
    #: η_a: approach mixture NLL.
    approach: float = 0.01
    #: η_w: width (contact pair distance) loss, measured in width_unit_m.
    width: float = 0.1
    #: η_q: L1 quality loss.
    quality: float = 10.0
    #: η_σ: binary cross-entropy of the decoded collision scores against the neighbour σ labels.
    collision: float = 0.1
    #: Unit of the width loss in metres (0.001 = millimetres).
    width_unit_m: float = 0.001
    #: Lower bound of the mixture weights σ_i inside the approach NLL (avoids log 0).
    sigma_floor: float = 1e-4
    #: VGN variant: negatives of the quality loss are the voxels within this many voxels of an
    #: observed surface voxel (VGN samples its grasps near surfaces); 0 = every voxel.
    vgn_negative_band_voxels: int = 0
    #: VGN variant: weight of a positive voxel against one negative in a plain mean of the quality
    #: BCE; 0 = positives and negatives averaged separately (balanced).
    vgn_positive_weight: float = 0.0
    #: VGN variant: voxels within this Chebyshev distance of a labelled grasp centre are positives
    #: too (carrying the best grasp centred in their neighbourhood); 0 = centre voxels only.
    vgn_positive_dilation_voxels: int = 0


@dataclass
class TrainConfig:
    """Optimisation schedule and run control."""

    #: Total iterations (one scene per iteration, batch size 1).
    iterations: int = 20000
    #: Initial Adam learning rate.
    lr: float = 1e-3
    #: Learning rate at the last iteration (exponential decay).
    lr_end: float = 1e-5
    #: The MLP losses start after this many U-Net iterations.
    mlp_warmup_iterations: int = 100
    #: Save a checkpoint every K iterations (0 = only at the end).
    checkpoint_every: int = 500
    #: Validate every V iterations (0 = only at the end).
    validate_every: int = 0
    #: Print a progress line every this many iterations.
    log_every: int = 10
    #: torch threads (0 = leave torch's default).
    threads: int = 0
    #: "cpu", "cuda" or "auto".
    device: str = "cpu"
    #: Stop cleanly (save + export) after this many minutes (0 = no limit).
    max_minutes: float = 0.0
    #: Deterministic algorithms (same seed → same weights on CPU).
    deterministic: bool = True
    #: Validation scenes evaluated at most (0 = all held-out scenes).
    max_val_scenes: int = 0
    #: Size the run to this wall-clock budget in minutes (0 = off; fresh runs only): once the
    #: step time is measured, `iterations` becomes the smaller of itself and the steps that fit
    #: the budget (less a reserve for the final validation and export), so the learning-rate
    #: schedule ends with the budget. Also a hard stop where max_minutes is 0. For a lent GPU
    #: whose speed is not known in advance; the fitted count is logged and stored in the card.
    fit_minutes: float = 0.0
    #: Steps timed before the first fit (the first few are skipped as warm-up).
    fit_probe_steps: int = 50
    #: A fine-tune: a fresh run starts from the model weights of this checkpoint file (relative
    #: paths are relative to the `training/` directory, e.g. `run-state/8app-crop32-v3/latest.pt`)
    #: with its own optimiser and learning-rate schedule; its model config and variant must equal
    #: the run's. The run's time (the card's CPU-hours) includes the checkpoint's. "" = random init.
    init_weights: str = ""


@dataclass
class ExportConfig:
    """Thresholds written to the model card."""

    contact_probability: float = 0.5
    quality: float = 0.5
    collision: float = 0.5


@dataclass
class Config:
    """A complete training configuration."""

    #: Model name written to the card (empty: derived from variant and base channels).
    name: str = ""
    #: "8app" (paper model), "1app-kappa" (single approach at inference) or "1app-cosine" ("wo κ").
    variant: str = "8app"
    #: Seed of every random process of the run.
    seed: int = 0
    model: ModelConfig = field(default_factory=ModelConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    data: DataConfig = field(default_factory=DataConfig)
    contacts: ContactConfig = field(default_factory=ContactConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    export: ExportConfig = field(default_factory=ExportConfig)

    @property
    def kappa_learned(self) -> bool:
        """Whether the model predicts κ (false for the "wo κ" cosine ablation)."""
        return self.variant != "1app-cosine"

    @property
    def single_approach(self) -> bool:
        """Whether inference keeps only the best approach direction."""
        return self.variant.startswith("1app")

    @property
    def model_name(self) -> str:
        """Card name."""
        return self.name or f"psgrasp-{self.variant}-b{self.model.base_channels}"

    def channels(self) -> list[int]:
        """Channels per U-Net level."""
        return [self.model.base_channels * 2**level for level in range(self.model.levels)]

    def feature_dim(self) -> int:
        """Size F of the concatenated encoder feature vector."""
        return sum(self.channels())

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (JSON/TOML serialisable)."""
        return dataclasses.asdict(self)

    def validate(self) -> None:
        """Raise :class:`ConfigError` for values that cannot work."""
        if self.variant not in VARIANTS:
            raise ConfigError(f"variant: {self.variant!r} is not one of {VARIANTS}")
        m = self.model
        if m.levels < 1:
            raise ConfigError("model.levels must be ≥ 1")
        if m.base_channels < 1 or m.blocks_per_level < 1:
            raise ConfigError("model.base_channels and model.blocks_per_level must be ≥ 1")
        if m.norm not in ("batch", "none"):
            raise ConfigError(f"model.norm: {m.norm!r} is not 'batch' or 'none'")
        if not m.mlp_hidden or any(h < 1 for h in m.mlp_hidden):
            raise ConfigError("model.mlp_hidden must be a non-empty list of positive widths")
        if not (m.kappa0 > 0):
            raise ConfigError("model.kappa0 must be > 0")
        g = self.grid
        if len(g.dims) != 3 or any(d < 1 for d in g.dims):
            raise ConfigError("grid.dims must be three positive sizes")
        if self.variant == "vgn" and any(d % 8 for d in g.dims):
            raise ConfigError(f"grid.dims {g.dims} must be divisible by 8 for the VGN-style network (3 stride-2 levels)")
        for d in g.dims:
            if d % 2 ** (m.levels - 1):
                raise ConfigError(f"grid.dims {g.dims} not divisible by 2^(levels-1) = {2 ** (m.levels - 1)}")
        for name in ("voxel_size_m", "max_opening_m", "approach_depth_m"):
            if not (getattr(g, name) > 0):
                raise ConfigError(f"grid.{name} must be > 0")
        if self.data.val_every < 2:
            raise ConfigError("data.val_every must be ≥ 2")
        if self.data.crop:
            crop = self.data.crop
            if len(crop) != 3 or any(c < 1 or c > d or c % 2 ** (m.levels - 1) for c, d in zip(crop, g.dims)):
                raise ConfigError(f"data.crop {crop} must be three sizes ≤ grid.dims {g.dims}, each a multiple of "
                                  f"2^(levels-1) = {2 ** (m.levels - 1)}")
        if not 0.0 <= self.data.crop_surface_share <= 1.0:
            raise ConfigError(f"data.crop_surface_share {self.data.crop_surface_share} must lie in [0, 1]")
        c = self.contacts
        if c.rule not in ("jittered-contact", "voxel-uniform"):
            raise ConfigError(f"contacts.rule: {c.rule!r} is not 'jittered-contact' or 'voxel-uniform'")
        if c.max_points < 1 or c.max_neighbours < 1 or c.predicted_points < 0 or c.uniform_points < 0:
            raise ConfigError("contacts.max_points/max_neighbours must be ≥ 1, predicted_points and uniform_points ≥ 0")
        if not (c.neighbour_radius_m > 0) or c.jitter_m < 0:
            raise ConfigError("contacts.neighbour_radius_m must be > 0 and jitter_m ≥ 0")
        if c.neighbour_radius_m > g.voxel_size_m:
            raise ConfigError("contacts.neighbour_radius_m must not exceed grid.voxel_size_m (hash cell)")
        lo = self.loss
        if len(lo.class_weights) != 3 or any(w < 0 for w in lo.class_weights):
            raise ConfigError("loss.class_weights must be three non-negative weights [empty, contact, gripper]")
        if not (lo.baseline_quality_power >= 0 and math.isfinite(lo.baseline_quality_power)):
            raise ConfigError("loss.baseline_quality_power must be finite and ≥ 0")
        if lo.vgn_negative_band_voxels < 0 or lo.vgn_positive_weight < 0 or lo.vgn_positive_dilation_voxels < 0:
            raise ConfigError("loss.vgn_negative_band_voxels, vgn_positive_weight, vgn_positive_dilation_voxels must be ≥ 0")
        if lo.focal_gamma < 0 or not (lo.width_unit_m > 0) or not (0 < lo.sigma_floor < 1):
            raise ConfigError("loss.focal_gamma ≥ 0, loss.width_unit_m > 0, 0 < loss.sigma_floor < 1 required")
        t = self.train
        if t.iterations < 0 or t.mlp_warmup_iterations < 0:
            raise ConfigError("train.iterations and train.mlp_warmup_iterations must be ≥ 0")
        if not (t.lr > 0 and t.lr_end > 0):
            raise ConfigError("train.lr and train.lr_end must be > 0")
        if not (t.max_minutes >= 0 and t.fit_minutes >= 0) or t.fit_probe_steps < 1:
            raise ConfigError("train.max_minutes and train.fit_minutes must be ≥ 0, train.fit_probe_steps ≥ 1")
        if t.device not in ("cpu", "cuda", "auto"):
            raise ConfigError(f"train.device: {t.device!r} is not cpu, cuda or auto")
        for name in ("contact_probability", "quality", "collision"):
            v = getattr(self.export, name)
            if not (0.0 <= v <= 1.0) or math.isnan(v):
                raise ConfigError(f"export.{name} must be in [0, 1]")


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: expected a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{where or 'config'}: unknown key(s) {unknown}")
    kwargs = {}
    defaults = cls()
    for name, value in data.items():
        default = getattr(defaults, name)
        key = f"{where}.{name}" if where else name
        if dataclasses.is_dataclass(default):
            kwargs[name] = _build(type(default), value, key)
            continue
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{key}: expected a boolean")
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ConfigError(f"{key}: expected an integer")
        elif isinstance(default, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ConfigError(f"{key}: expected a number")
            value = float(value)
        elif isinstance(default, str):
            if not isinstance(value, str):
                raise ConfigError(f"{key}: expected a string")
        elif isinstance(default, list):
            if not isinstance(value, list):
                raise ConfigError(f"{key}: expected a list")
            if default and isinstance(default[0], float):
                value = [float(v) for v in value]
        kwargs[name] = value
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a :class:`Config` from a nested dict (missing keys take defaults)."""
    cfg = _build(Config, data, "")
    cfg.validate()
    return cfg


#: Top-level key naming the file a config builds on (a path relative to the config's folder).
EXTENDS_KEY = "extends"


def _merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``override`` laid over it: tables merge key by key, other values replace."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _read_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The TOML table of ``path`` with its ``extends`` chain resolved (base first, then this file)."""
    resolved = path.resolve()
    if resolved in chain:
        cycle = " -> ".join(str(p) for p in (*chain, resolved))
        raise ConfigError(f"config {path}: '{EXTENDS_KEY}' forms a cycle ({cycle})")
    try:
        with path.open("rb") as f:
            data = tomllib.load(f)
    except OSError as e:
        raise ConfigError(f"cannot read config {path}: {e}") from e
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"config {path} is not valid TOML: {e}") from e
    base_name = data.pop(EXTENDS_KEY, None)
    if base_name is None:
        return data
    if not isinstance(base_name, str) or not base_name:
        raise ConfigError(f"config {path}: '{EXTENDS_KEY}' must be a file name")
    base = _read_toml(path.parent / base_name, (*chain, resolved))
    return _merge(base, data)


def load_config(path: str | Path) -> Config:
    """Load and validate a TOML configuration file.

    A file may start from another one with ``extends = "base.toml"`` (relative to its own folder):
    its tables are laid over the base's key by key, so a variant states only what it changes.
    Chains are followed; a cycle or a missing base is an error that names the files."""
    return config_from_dict(_read_toml(Path(path)))
