"""Training loop, validation and the run-directory workflow.

Determinism: every random draw of iteration k comes from a generator seeded with (seed, k) and the
scene order of epoch e from one seeded with (seed, e); a resumed run therefore continues exactly
like an uninterrupted one (same weights on CPU).
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import replace
from pathlib import Path

import torch

from .checkpoint import DatasetInfo, RunError, load_checkpoint, load_checkpoint_file, save_checkpoint, write_json
from .config import Config
from .data import Scene, SceneDataset, crop_origin, crop_scene, flip_scene
from .decode import class_probabilities, sample_features, sample_grid, subvoxel_points
from .export import export_model
from .kappa_ceiling import earned_kappa
from .losses import (GraspIndex, contact_voxel_points, focal_loss, grasp_loss, grasp_targets,
                     predicted_voxel_points, uniform_contact_points)
from .model import CLASSES, GraspNet
from .pickcheck import PickCheckConfig, PickStats, pick_check, scene_candidates

#: The `training/` directory (relative train.init_weights paths start here).
TRAINING_DIR = Path(__file__).resolve().parent.parent

LOG_FIELDS = ["step", "loss", "label", "grasp", "baseline", "approach", "width", "quality", "collision", "points",
              "hit_rate", "lr", "seconds", "elapsed_s"]
_MASK63 = (1 << 63) - 1


def derive_seed(*parts: int) -> int:
    """Mix integers into a 63-bit seed (splitmix64 steps)."""
    x = 0x9E3779B97F4A7C15
    for p in parts:
        x = (x ^ (int(p) & 0xFFFFFFFFFFFFFFFF)) * 0xBF58476D1CE4E5B9 & 0xFFFFFFFFFFFFFFFF
        x = (x ^ (x >> 31)) * 0x94D049BB133111EB & 0xFFFFFFFFFFFFFFFF
        x ^= x >> 29
    return x & _MASK63


def setup_torch(cfg: Config) -> torch.device:
    """Threads, determinism and the device."""
    if cfg.train.threads > 0:
        torch.set_num_threads(cfg.train.threads)
    if cfg.train.deterministic:
        torch.use_deterministic_algorithms(True, warn_only=True)
    dev = cfg.train.device
    if dev == "auto":
        dev = "cuda" if torch.cuda.is_available() else "cpu"
    if dev == "cuda" and not torch.cuda.is_available():
        raise RunError("train.device = cuda but no CUDA device is available")
    return torch.device(dev)


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


def learning_rate(cfg: Config, step: int) -> float:
    """Exponential decay from lr (step 0) to lr_end (last step)."""
    t = cfg.train
    frac = step / max(1, t.iterations - 1)
    return t.lr * (t.lr_end / t.lr) ** min(1.0, frac)


#: Steps at the start of a budget-fitted run that are not timed (CUDA start-up, first allocations).
FIT_WARMUP_STEPS = 3
#: Share of the budget after which the fit is repeated with every step timed so far (a scene cache
#: filling during the first epoch makes the first steps slower than the rest).
FIT_REFIT_FRACTION = 0.2


def fitted_iterations(step: int, elapsed_s: float, seconds_per_step: float, budget_s: float, cap: int) -> int:
    """Iterations that end a run within `budget_s`: `step` plus the steps of `seconds_per_step`
    that fit the time left after `elapsed_s`, less a reserve for the final validation and export
    (5 % of the budget, at least 10 s); never more than `cap`, never fewer than `step + 1`."""
    reserve = max(10.0, 0.05 * budget_s)
    steps = int(max(0.0, budget_s - reserve - elapsed_s) / max(seconds_per_step, 1e-9))
    return max(step + 1, min(cap, step + steps))


class BudgetFit:
    """`train.fit_minutes`: times the steps of a fresh run and sizes `train.iterations` to the
    budget, once after `fit_probe_steps` steps and once more at FIT_REFIT_FRACTION of it."""

    def __init__(self, minutes: float, probe_steps: int, start: int, cap: int):
        self.budget_s = 60.0 * minutes
        self.cap = cap
        self.warm_step = start + FIT_WARMUP_STEPS
        self.probe_step = self.warm_step + probe_steps
        self.warm_elapsed: float | None = None
        self.refitted = False

    def after_step(self, step: int, elapsed_s: float) -> tuple[int, float] | None:
        """(new iterations, measured s/step) when this step is a fitting point, else None."""
        if step == self.warm_step:
            self.warm_elapsed = elapsed_s
            return None
        if self.warm_elapsed is None or step < self.probe_step:
            return None
        if step > self.probe_step:
            if self.refitted or elapsed_s < FIT_REFIT_FRACTION * self.budget_s:
                return None
            self.refitted = True
        rate = (elapsed_s - self.warm_elapsed) / (step - self.warm_step)
        return fitted_iterations(step, elapsed_s, rate, self.budget_s, self.cap), rate


def scene_to(scene: Scene, device: torch.device) -> Scene:
    """Copy of a scene with its tensors on a device."""
    if device.type == "cpu":
        return scene
    return replace(scene, normals=scene.normals.to(device), labels=scene.labels.to(device),
                   contact=scene.contact.to(device), baseline=scene.baseline.to(device),
                   width=scene.width.to(device), quality=scene.quality.to(device),
                   collision_free=scene.collision_free.to(device))


def targets_to(targets, device: torch.device):
    """Move GraspTargets to a device."""
    if device.type == "cpu":
        return targets
    nb = replace(targets.neighbours, idx=targets.neighbours.idx.to(device), dist=targets.neighbours.dist.to(device))
    return replace(targets, neighbours=nb, has=targets.has.to(device), nu_hat=targets.nu_hat.to(device),
                   width_hat=targets.width_hat.to(device), quality=targets.quality.to(device),
                   collision=targets.collision.to(device))


def scene_for_step(ds: SceneDataset, cfg: Config, step: int) -> tuple[Scene, torch.Generator]:
    """The (augmented, and with data.crop cropped) training scene of an iteration and the
    iteration's generator."""
    n = len(ds.train_entries)
    epoch, pos = divmod(step, n)
    perm = torch.randperm(n, generator=torch.Generator().manual_seed(derive_seed(cfg.seed, 1, epoch)))
    scene = ds.scene(ds.train_entries[int(perm[pos])])
    g = torch.Generator().manual_seed(derive_seed(cfg.seed, 2, step))
    if cfg.data.flip_augmentation:
        fx, fy = (torch.rand(2, generator=g) < 0.5).tolist()
        scene = flip_scene(scene, fx, fy)
    if cfg.data.crop:
        origin = crop_origin(scene, cfg.data.crop, g, cfg.data.crop_surface_share)
        scene = crop_scene(scene, origin, cfg.data.crop)
    return scene, g


def _no_mark(phase: str) -> None:
    """The default phase marker of :func:`training_step` (timing off)."""


def training_step(net: GraspNet, scene: Scene, cfg: Config, g: torch.Generator, device: torch.device,
                  with_mlp: bool, mark=_no_mark) -> dict[str, torch.Tensor | float]:
    """Forward pass and loss of one scene (no optimiser step).

    mark(phase) is called as each phase ends (``psgrasp_training profile`` times them)."""
    dev_scene = scene_to(scene, device)
    logits, encs = net.unet(dev_scene.normals.unsqueeze(0))
    mark("unet forward")
    label = focal_loss(logits, dev_scene.labels.unsqueeze(0), cfg.loss.class_weights, cfg.loss.focal_gamma)
    mark("label loss")
    out: dict[str, torch.Tensor | float] = {"label": label}
    if with_mlp:
        probs = class_probabilities(logits)
        points = contact_voxel_points(scene, cfg, g)
        extra = predicted_voxel_points(scene, probs[0, 1].detach().cpu(), cfg, g)
        points = torch.cat([points, extra, uniform_contact_points(scene, cfg, g)], 0)
        mark("contact points")
        index = GraspIndex(scene.contact, cfg.contacts.neighbour_radius_m)
        targets = targets_to(grasp_targets(scene, index, points, cfg), device)
        pts = points.to(device)
        mark("grasp targets")
        features = sample_features(encs, pts, scene.extent_m)
        mark("feature sampling")
        mlp_out = net.mlp(features)
        mark("mlp forward")
        terms = grasp_loss(dev_scene, targets, pts, mlp_out, probs, cfg, cfg.grid.approach_depth_m)
        mark("grasp loss")
        out.update(terms)
        out["points"] = float(len(points))
        out["hit_rate"] = float(targets.has.float().mean()) if len(points) else 0.0
        out["loss"] = cfg.loss.label * label + cfg.loss.grasp * terms["grasp"]
    else:
        out["loss"] = cfg.loss.label * label
    return out


@torch.no_grad()
def evaluate(net: GraspNet, ds: SceneDataset, cfg: Config, device: torch.device, max_scenes: int = 0) -> dict:
    """Validation metrics on the held-out scenes.

    Also contact precision/recall of P_contact ≥ export.contact_probability (the inference rule) and
    the mean κ at the points.

    IoU per class of the argmax label grid (summed over scenes); at training-rule points in true
    contact voxels (fixed seed per scene): baseline angle error = directed angle between ν and the
    closest neighbour baseline, width error = |w − that neighbour's width|, quality MAE of the
    decoded q against the max neighbour quality, and the neighbour hit-rate. ``picks``: the pick
    check of :mod:`psgrasp_training.pickcheck` (what the evaluation would execute, against the labels).
    """
    net.eval()
    entries = ds.val_entries[: max_scenes] if max_scenes > 0 else ds.val_entries
    inter = torch.zeros(3, dtype=torch.float64)
    union = torch.zeros(3, dtype=torch.float64)
    tp = n_pred = n_true = 0
    angles, width_err, q_err, kappas, hits, npts = [], [], [], [], 0, 0
    mean_angles, earned, kappa_hit, counts = [], [], [], []
    picks = PickStats(PickCheckConfig())
    for entry in entries:
        scene = ds.scene(entry)
        dev_scene = scene_to(scene, device)
        logits, encs = net.unet(dev_scene.normals.unsqueeze(0))
        picks.add(scene, int(entry.get("objects", 0)),
                  scene_candidates(net, scene.normals, scene.extent_m, scene.voxel_size_m,
                                   cfg.export.contact_probability, cfg.grid.approach_depth_m, picks.pc,
                                   unet_out=(logits, encs)))
        pred = logits[0].argmax(0).cpu()
        for c in range(3):
            p, t = pred == c, scene.labels == c
            inter[c] += (p & t).sum()
            union[c] += (p | t).sum()
        probs = class_probabilities(logits)
        p_c = probs[0, 1].cpu() >= cfg.export.contact_probability
        t_c = scene.labels == 1
        tp += int((p_c & t_c).sum())
        n_pred += int(p_c.sum())
        n_true += int(t_c.sum())
        g = torch.Generator().manual_seed(derive_seed(cfg.seed, 3, scene.index))
        points = contact_voxel_points(scene, cfg, g)
        if len(points) == 0:
            continue
        targets = grasp_targets(scene, GraspIndex(scene.contact, cfg.contacts.neighbour_radius_m), points, cfg)
        pts = points.to(device)
        out = {k: v.cpu() for k, v in net.mlp(sample_features(encs, pts, scene.extent_m)).items()}
        q = sample_grid(probs[:, 1:2], pts, scene.extent_m)[:, 0].cpu() * out["quality_prior"]
        q_err.append((q - targets.quality).abs())
        kappas.append(out["kappa"])
        npts += len(points)
        h = targets.has.nonzero().reshape(-1)
        hits += len(h)
        if len(h):
            idx = targets.neighbours.idx[h]
            valid = idx >= 0
            b_n = scene.baseline[idx.clamp(min=0)]
            cos = (b_n * out["baseline"][h].unsqueeze(1)).sum(-1).clamp(-1, 1)
            ang = torch.where(valid, torch.rad2deg(torch.acos(cos)), torch.full_like(cos, math.inf))
            best_ang, best = ang.min(1)
            angles.append(best_ang)
            counts.append(valid.sum(1))
            n_valid = counts[-1].clamp_min(1)
            mean_angles.append(torch.where(valid, ang, torch.zeros_like(ang)).sum(1) / n_valid)
            earned.append(earned_kappa(cos, valid))
            kappa_hit.append(out["kappa"][h])
            w_best = scene.width[idx.clamp(min=0).gather(1, best.unsqueeze(1)).squeeze(1)]
            width_err.append((out["width"][h] - w_best).abs() * 1000.0)
    net.train()
    iou = {name: float(inter[c] / union[c]) if union[c] > 0 else 0.0 for c, name in enumerate(CLASSES)}

    def mean(xs):
        return float(torch.cat(xs).mean()) if xs and sum(len(x) for x in xs) else 0.0

    return {"scenes": len(entries), "iou": iou, "baseline_angle_error_deg": mean(angles),
            "width_error_mm": mean(width_err), "quality_mae": mean(q_err), "points": npts,
            "hit_rate": hits / npts if npts else 0.0, "kappa_mean": mean(kappas),
            "contact_precision": tp / n_pred if n_pred else 0.0, "contact_recall": tp / n_true if n_true else 0.0,
            "contact_voxels_predicted": n_pred, "contact_voxels_true": n_true, "picks": picks.result(),
            "baseline_angle_error_by_neighbours": angle_error_by_neighbours(angles, counts),
            **earned_kappa_figures(mean_angles, earned, kappa_hit, cfg.model.kappa0)}


#: Neighbour-count bands of :func:`angle_error_by_neighbours`: (name, fewest, most) labels.
NEIGHBOUR_BANDS = (("1", 1, 1), ("2-3", 2, 3), ("4+", 4, 1 << 30))


def angle_error_by_neighbours(angles: list[torch.Tensor], counts: list[torch.Tensor]) -> dict:
    """Mean baseline angle error (to the nearest label) and point count per band of neighbour-label
    count. A point with one label is judged against a single sample of the grasps its contact
    allows, so its error carries the labels' own spread; points with many labels measure ν itself."""
    out = {}
    a = torch.cat(angles) if angles else torch.zeros(0)
    c = torch.cat(counts) if counts else torch.zeros(0, dtype=torch.long)
    for name, lo, hi in NEIGHBOUR_BANDS:
        m = (c >= lo) & (c <= hi)
        out[name] = {"points": int(m.sum()), "mean_deg": float(a[m].mean()) if bool(m.any()) else 0.0}
    return out


def earned_kappa_figures(mean_angles: list[torch.Tensor], earned: list[torch.Tensor], predicted: list[torch.Tensor],
                         kappa0: float) -> dict:
    """Validation figures of the κ the predicted baselines earn (kappa_ceiling.earned_kappa): the mean
    angle of ν to all neighbour labels, the median earned κ, the share of points above κ0, and
    Spearman's rank correlation of the predicted κ with the earned one (does the κ head find the
    points where ν is good?)."""
    if not earned or sum(len(e) for e in earned) == 0:
        return {"baseline_mean_neighbour_angle_deg": 0.0, "kappa_earned_median": 0.0, "kappa_earned_above_floor": 0.0,
                "kappa_rank_correlation": 0.0}
    e = torch.cat(earned)
    return {"baseline_mean_neighbour_angle_deg": float(torch.cat(mean_angles).mean()),
            "kappa_earned_median": float(e.median()), "kappa_earned_above_floor": float((e > kappa0).double().mean()),
            "kappa_rank_correlation": spearman(torch.cat(predicted), e)}


def spearman(a: torch.Tensor, b: torch.Tensor) -> float:
    """Spearman's rank correlation of two 1-D tensors (ties ranked in order; 0 when either is constant)."""
    if len(a) < 2:
        return 0.0
    ra = torch.argsort(torch.argsort(a.to(torch.float64), stable=True)).to(torch.float64)
    rb = torch.argsort(torch.argsort(b.to(torch.float64), stable=True)).to(torch.float64)
    if bool((a == a[0]).all()) or bool((b == b[0]).all()):
        return 0.0
    ra, rb = ra - ra.mean(), rb - rb.mean()
    return float((ra * rb).sum() / (ra.norm() * rb.norm()))


def _open_log(run_dir: Path, resume_step: int, fields: list[str] = LOG_FIELDS):
    path = run_dir / "log.csv"
    rows = []
    if resume_step > 0 and path.is_file():
        with path.open() as f:
            rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]
    f = path.open("w", newline="")
    w = csv.DictWriter(f, fieldnames=fields)
    w.writeheader()
    w.writerows(rows)
    f.flush()
    return f, w


def init_weights_path(cfg: Config) -> Path:
    """train.init_weights as a path (relative ones are relative to the `training/` directory)."""
    path = Path(cfg.train.init_weights)
    return path if path.is_absolute() else TRAINING_DIR / path


def same_network(a: Config, b: Config) -> bool:
    """Whether checkpoints of `a` load into the network of `b` (same model config and variant)."""
    return a.to_dict()["model"] == b.to_dict()["model"] and a.variant == b.variant


def init_from_weights(net: torch.nn.Module, cfg: Config, log=print) -> float:
    """Load train.init_weights' model weights into `net` (a fine-tune's start); returns the
    checkpoint's training time in seconds, which the fine-tune's time continues."""
    path = init_weights_path(cfg)
    state = load_checkpoint_file(path)
    old: Config = state["config"]
    if not same_network(old, cfg):
        raise RunError(f"train.init_weights {path}: its model config or variant differs from this run's")
    net.load_state_dict(state["model"])
    elapsed = float(state.get("elapsed_s", 0.0))
    log(f"initialised from {path} (step {state['step']}, {elapsed / 3600:.2f} h of training)")
    return elapsed


def fit(cfg: Config, data: Path, run_dir: Path, make_net, step_fn, evaluate_fn, export_fn, log_fields: list[str],
        describe: str, progress, resume: bool = False, export: bool = True, log=print,
        stop_at: int | None = None) -> dict:
    """The training loop every model variant shares: run directory, exact resume, learning-rate
    schedule, per-step CSV log, validation, checkpoints, the wall-clock and --stop-at limits and
    the final export.

    make_net(cfg) builds the network; step_fn(net, scene, g, device, step) returns the loss terms
    of one scene ("loss" included); evaluate_fn(net, ds, cfg, device, max_scenes) the validation
    metrics; export_fn(net, cfg, info, out_dir, step, validation, reference_scene, log=) writes the
    model directory; progress(values) the middle of a progress line; describe names the model."""
    run_dir = Path(run_dir)
    device = setup_torch(cfg)
    ds = SceneDataset(data, cfg)
    apply_dataset_geometry(cfg, ds.info)
    torch.manual_seed(cfg.seed)
    net = make_net(cfg)
    start = 0
    elapsed0 = 0.0
    opt_state = None
    if resume:
        state = load_checkpoint(run_dir)
        old: Config = state["config"]
        if not same_network(old, cfg) or old.seed != cfg.seed:
            raise RunError(f"{run_dir}: --resume with a different model, variant or seed than the checkpoint")
        if state["dataset"].manifest_sha256 != ds.info.manifest_sha256:
            log("warning: the dataset manifest changed since the checkpoint (resuming anyway)")
        net.load_state_dict(state["model"])
        start, elapsed0, opt_state = state["step"], state.get("elapsed_s", 0.0), state["optimizer"]
    elif cfg.train.init_weights:
        elapsed0 = init_from_weights(net, cfg, log)
    net.to(device).train()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.train.lr)
    if opt_state is not None:
        opt.load_state_dict(opt_state)
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(run_dir / "config.json", cfg.to_dict())
    write_json(run_dir / "dataset.json", ds.info.__dict__)
    logf, logw = _open_log(run_dir, start, log_fields)
    t_cfg = cfg.train
    budget = None
    if t_cfg.fit_minutes > 0:
        if resume:
            log(f"train.fit_minutes ignored on --resume: the run keeps iterations = {t_cfg.iterations}")
        else:
            budget = BudgetFit(t_cfg.fit_minutes, t_cfg.fit_probe_steps, start, t_cfg.iterations)
            if t_cfg.max_minutes == 0:
                t_cfg.max_minutes = t_cfg.fit_minutes
    log(f"training {describe}: {ds.info.train_scenes} train / {ds.info.val_scenes} val scenes, "
        f"{sum(p.numel() for p in net.parameters())} parameters, device {device}, threads {torch.get_num_threads()}, "
        f"steps {start}..{t_cfg.iterations}")
    t0 = time.monotonic()
    validation = None
    step = start
    stopped = False
    try:
        while step < t_cfg.iterations:
            if t_cfg.max_minutes > 0 and time.monotonic() - t0 > 60.0 * t_cfg.max_minutes:
                log(f"wall-clock limit of {t_cfg.max_minutes} min reached at step {step}: stopping")
                stopped = True
                break
            if stop_at is not None and step >= stop_at:
                log(f"stopping at step {step} (--stop-at)")
                stopped = True
                break
            ts = time.monotonic()
            lr = learning_rate(cfg, step)
            for group in opt.param_groups:
                group["lr"] = lr
            scene, g = scene_for_step(ds, cfg, step)
            out = step_fn(net, scene, g, device, step)
            loss = out["loss"]
            if not torch.isfinite(loss):
                raise RunError(f"non-finite loss at step {step} (scene {scene.index}): "
                               + ", ".join(f"{k}={float(v):.4g}" for k, v in out.items()))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            secs = time.monotonic() - ts
            out = {k: float(v.detach()) if isinstance(v, torch.Tensor) else v for k, v in out.items()}
            row = {k: f"{out[k]:.6g}" if k in out else "" for k in log_fields}
            row.update(step=step, lr=f"{lr:.6g}", seconds=f"{secs:.3f}",
                       elapsed_s=f"{elapsed0 + time.monotonic() - t0:.1f}")
            logw.writerow(row)
            fitted = budget.after_step(step, time.monotonic() - t0) if budget is not None else None
            if fitted is not None and fitted[0] != t_cfg.iterations:
                t_cfg.iterations = fitted[0]
                write_json(run_dir / "config.json", cfg.to_dict())
                log(f"fitted to {t_cfg.fit_minutes} min at step {step}: {fitted[1]:.3f} s/step, "
                    f"iterations {t_cfg.iterations}")
            if step % t_cfg.log_every == 0 or step == t_cfg.iterations:
                logf.flush()
                log(f"step {step}/{t_cfg.iterations} {progress(out)} lr {lr:.2e} {secs:.2f} s/step")
            if t_cfg.validate_every > 0 and step % t_cfg.validate_every == 0 and step < t_cfg.iterations:
                validation = evaluate_fn(net, ds, cfg, device, t_cfg.max_val_scenes)
                log(f"validation @ {step}: {validation}")
            if t_cfg.checkpoint_every > 0 and step % t_cfg.checkpoint_every == 0:
                save_checkpoint(run_dir, step, cfg, net, ds.info, opt, validation, elapsed0 + time.monotonic() - t0)
    finally:
        logf.close()
    validation = evaluate_fn(net, ds, cfg, device, t_cfg.max_val_scenes)
    log(f"validation @ {step}: {validation}")
    write_json(run_dir / "validation.json", {"step": step, **validation})
    elapsed_final = elapsed0 + time.monotonic() - t0
    save_checkpoint(run_dir, step, cfg, net, ds.info, opt, validation, elapsed_final)
    if export:
        ref = ds.root / (ds.val_entries or ds.train_entries)[0]["file"]
        export_fn(net.cpu(), cfg, ds.info, run_dir / "model", step, validation, ref, log=log, elapsed_s=elapsed_final)
        log(f"exported {run_dir / 'model'}")
    if stopped:
        log("stopped early; continue with --resume")
    return validation


def train(cfg: Config, data: Path, run_dir: Path, resume: bool = False, export: bool = True, log=print,
          stop_at: int | None = None) -> dict:
    """Train (or resume) a run; returns the final validation metrics.

    stop_at: stop (save, validate, export) once this step is reached, like the wall-clock limit
    (the learning-rate schedule still spans train.iterations; resume continues it)."""

    def step_fn(net, scene, g, device, step):
        return training_step(net, scene, cfg, g, device, step >= cfg.train.mlp_warmup_iterations)

    def progress(out):
        parts = " ".join(f"{k} {float(out[k]):.4f}" for k in ("loss", "label", "baseline", "approach", "width",
                                                               "quality", "collision") if k in out)
        return parts + (f" hit {out['hit_rate']:.2f}" if "hit_rate" in out else "")

    return fit(cfg, data, run_dir, GraspNet, step_fn, evaluate, export_model, LOG_FIELDS, cfg.model_name, progress,
               resume=resume, export=export, log=log, stop_at=stop_at)


def hitrate_report(cfg: Config, data: Path, scenes: int, radii_m: list[float], log=print) -> dict:
    """Neighbour hit-rate (share of points with ≥ 1 true grasp within r) of the contact-point rules."""
    ds = SceneDataset(data, cfg)
    entries = (ds.train_entries + ds.val_entries)[:scenes]

    results = {}
    for rule in ("voxel-uniform", "jittered-contact", "subvoxel-centres"):
        for r in radii_m:
            c = replace(cfg, contacts=replace(cfg.contacts, rule=rule if rule != "subvoxel-centres" else "voxel-uniform",
                                              neighbour_radius_m=r, max_points=10**9))
            hit = tot = nsum = 0
            for e in entries:
                scene = ds.scene(e)
                g = torch.Generator().manual_seed(derive_seed(cfg.seed, 4, scene.index))
                if rule == "subvoxel-centres":
                    vox = torch.nonzero(scene.labels.reshape(-1) == 1).reshape(-1)
                    pts = subvoxel_points(vox, scene.dims, scene.voxel_size_m)
                else:
                    pts = contact_voxel_points(scene, c, g)
                nb = GraspIndex(scene.contact, max(r, scene.voxel_size_m)).query(pts, r, c.contacts.max_neighbours)
                hit += int((nb.count > 0).sum())
                nsum += int(nb.count.sum())
                tot += len(pts)
            results[(rule, r)] = (hit / max(tot, 1), nsum / max(hit, 1), tot)
            log(f"{rule:17s} r = {r * 1000:4.1f} mm: hit-rate {hit / max(tot, 1):.3f}, "
                f"mean neighbours (hits) {nsum / max(hit, 1):.1f}, points {tot}")
    return results


def evaluate_run(run_dir: Path, data: Path, checkpoint: str = "latest.pt", max_scenes: int = 0, log=print) -> dict:
    """Validation metrics of a checkpoint (same split as its training run)."""
    state = load_checkpoint(run_dir, checkpoint)
    cfg: Config = state["config"]
    device = setup_torch(cfg)
    ds = SceneDataset(data, cfg)
    net = GraspNet(cfg)
    net.load_state_dict(state["model"])
    net.to(device)
    val = evaluate(net, ds, cfg, device, max_scenes)
    log(f"validation of {run_dir} @ {state['step']}: {val}")
    return val


def pick_check_run(run_dir: Path, data: Path, checkpoints: list[str], max_scenes: int = 0, log=print,
                   all_scenes: bool = False) -> dict:
    """The pick check (:mod:`psgrasp_training.pickcheck`) of checkpoints of a run on its held-out
    scenes (`all_scenes`: on every scene of `data`); ``["all"]`` takes every ``step_*.pt``.
    Returns {checkpoint: {group: figures}}."""
    if checkpoints == ["all"]:
        checkpoints = sorted(p.name for p in (Path(run_dir) / "checkpoints").glob("step_*.pt"))
    results = {}
    for name in checkpoints:
        state = load_checkpoint(run_dir, name)
        cfg: Config = state["config"]
        setup_torch(cfg)
        ds = SceneDataset(data, cfg)
        net = GraspNet(cfg)
        net.load_state_dict(state["model"])
        res = pick_check(net, ds, cfg, max_scenes, all_scenes=all_scenes)
        results[name] = {"step": state["step"], **res}
        row = "  ".join(f"{g} P@k {v['precision_at_k']:.3f} top1 {v['top1']:.2f} none {v['no_pick']:.2f} "
                        f"objects {v['object_recall']:.2f}" for g, v in res.items() if g != "all")
        log(f"{name} (step {state['step']}): all P@k {res['all']['precision_at_k']:.3f}  {row}")
    return results
