"""Command line: ``python -m psgrasp_training {train,export,init,evaluate,pickcheck,profile,hitrate,kappa-ceiling} ...``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m psgrasp_training", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train a model (resumable), validate and export (variant = \"vgn\": the VGN-style baseline)")
    t.add_argument("--config", required=True, type=Path, help="TOML config (training/configs/*.toml)")
    t.add_argument("--data", required=True, type=Path, help="psgrasp dataset directory (manifest.json + scenes)")
    t.add_argument("--out", required=True, type=Path, help="run directory (checkpoints, log.csv, model/)")
    t.add_argument("--resume", action="store_true", help="continue from RUN_DIR/checkpoints/latest.pt")
    t.add_argument("--max-minutes", type=float, default=None, help="wall-clock limit; stops cleanly, saves, exports")
    t.add_argument("--fit-minutes", type=float, default=None,
                   help="size train.iterations to this wall-clock budget once the step time is measured (fresh runs)")
    t.add_argument("--iterations", type=int, default=None, help="override train.iterations")
    t.add_argument("--threads", type=int, default=None, help="override train.threads")
    t.add_argument("--device", default=None, help="override train.device (cpu, cuda, auto)")
    t.add_argument("--stop-at", type=int, default=None, help="stop cleanly at this step (resumable)")
    t.add_argument("--no-export", action="store_true", help="do not export RUN_DIR/model at the end")

    e = sub.add_parser("export", help="export a run to unet.onnx + mlp.onnx + card.json (vgn runs: vgn.onnx + card.json)")
    e.add_argument("--run", required=True, type=Path, help="run directory")
    e.add_argument("--out", required=True, type=Path, help="model directory to write")
    e.add_argument("--reference", type=Path, default=None, help="scene file for reference.safetensors")
    e.add_argument("--contact-probability", type=float, default=None,
                   help="card contact threshold (default: the config's export.contact_probability)")
    e.add_argument("--checkpoint", default="latest.pt", help="file name under RUN/checkpoints")
    e.add_argument("--variant", default=None, choices=["8app", "1app-kappa"],
                   help="export an 8app run as the inference-time ablation 1app-kappa (\"w κ + 1app\": "
                        "same training, one approach per grasp) or back")

    i = sub.add_parser("init", help="create a run directory holding an untrained model (step 0)")
    i.add_argument("--config", required=True, type=Path)
    i.add_argument("--out", required=True, type=Path, help="run directory")
    i.add_argument("--data", type=Path, default=None, help="dataset whose grid/gripper geometry to record")

    v = sub.add_parser("evaluate", help="validation metrics of a run's checkpoint on its held-out scenes")
    v.add_argument("--run", required=True, type=Path)
    v.add_argument("--data", required=True, type=Path)
    v.add_argument("--checkpoint", default="latest.pt", help="file name under RUN/checkpoints")
    v.add_argument("--max-scenes", type=int, default=0)

    k = sub.add_parser("pickcheck", help="the pick check (top picks against the labels) of a run's checkpoints")
    k.add_argument("--run", required=True, type=Path)
    k.add_argument("--data", required=True, type=Path)
    k.add_argument("--checkpoint", nargs="+", default=["latest.pt"],
                   help="file names under RUN/checkpoints, or `all` for every step_*.pt")
    k.add_argument("--max-scenes", type=int, default=0)
    k.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    k.add_argument("--all-scenes", action="store_true",
                   help="check every scene of --data (a dataset made for checking), not the run's held-out split")

    f = sub.add_parser("profile", help="time the phases of training steps (nothing saved)")
    f.add_argument("--config", required=True, type=Path)
    f.add_argument("--data", required=True, type=Path)
    f.add_argument("--steps", type=int, default=10)
    f.add_argument("--start-step", type=int, default=1000,
                   help="step to take the scenes, augmentation and MLP warm-up state from")
    f.add_argument("--threads", type=int, default=None, help="override train.threads")

    h = sub.add_parser("hitrate", help="measure the neighbour hit-rate of the contact-point rules on a dataset")
    h.add_argument("--config", required=True, type=Path)
    h.add_argument("--data", required=True, type=Path)
    h.add_argument("--scenes", type=int, default=10)
    h.add_argument("--radius-mm", type=float, nargs="*", default=[3.0, 4.5, 6.0])

    c = sub.add_parser("kappa-ceiling",
                       help="the κ the labels allow: per training point, the maximum-likelihood κ of its neighbour baselines")
    c.add_argument("--config", required=True, type=Path)
    c.add_argument("--data", required=True, type=Path)
    c.add_argument("--scenes", type=int, default=20)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    from .checkpoint import RunError
    from .config import ConfigError, load_config
    from .data import DatasetError
    from .export import ExportError

    try:
        if args.command == "train":
            from .train import train

            cfg = load_config(args.config)
            if args.iterations is not None:
                cfg.train.iterations = args.iterations
            if args.threads is not None:
                cfg.train.threads = args.threads
            if args.device is not None:
                cfg.train.device = args.device
            if args.max_minutes is not None:
                cfg.train.max_minutes = args.max_minutes
            if args.fit_minutes is not None:
                cfg.train.fit_minutes = args.fit_minutes
            cfg.validate()
            if cfg.variant == "vgn":
                from .vgn import train_vgn as train
            train(cfg, args.data, args.out, resume=args.resume, export=not args.no_export, stop_at=args.stop_at)
        elif args.command == "export":
            from .checkpoint import load_checkpoint
            from .export import export_run

            if load_checkpoint(args.run, args.checkpoint)["config"].variant == "vgn":
                from .vgn import export_vgn_run

                if args.variant not in (None, "vgn") or args.contact_probability is not None:
                    raise ExportError("a vgn run exports only as vgn (no --variant/--contact-probability)")
                card = export_vgn_run(args.run, args.out, args.reference, checkpoint=args.checkpoint)
            else:
                card = export_run(args.run, args.out, args.reference, args.contact_probability,
                                  checkpoint=args.checkpoint, variant=args.variant)
            print(f"wrote {args.out} ({card['name']}, {card['training']['iterations']} iterations)")
        elif args.command == "init":
            from .train import init_run

            init_run(load_config(args.config), args.out, args.data)
            print(f"wrote untrained run {args.out}")
        elif args.command == "evaluate":
            from .train import evaluate_run

            evaluate_run(args.run, args.data, args.checkpoint, args.max_scenes)
        elif args.command == "pickcheck":
            from .checkpoint import write_json
            from .train import pick_check_run

            results = pick_check_run(args.run, args.data, args.checkpoint, args.max_scenes,
                                     all_scenes=args.all_scenes)
            if args.json is not None:
                write_json(args.json, results)
        elif args.command == "profile":
            from .profile import profile_steps

            cfg = load_config(args.config)
            if args.threads is not None:
                cfg.train.threads = args.threads
            cfg.validate()
            profile_steps(cfg, args.data, args.steps, args.start_step)
        elif args.command == "hitrate":
            from .train import hitrate_report

            hitrate_report(load_config(args.config), args.data, args.scenes, [r / 1000 for r in args.radius_mm])
        elif args.command == "kappa-ceiling":
            from .kappa_ceiling import kappa_ceiling_report

            kappa_ceiling_report(load_config(args.config), args.data, args.scenes)
    except (ConfigError, DatasetError, RunError, ExportError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
