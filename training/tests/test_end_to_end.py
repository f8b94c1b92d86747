import json
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch
from safetensors.numpy import load_file

from psgrasp_training.__main__ import main
from psgrasp_training.checkpoint import load_checkpoint
from psgrasp_training.decode import class_probabilities, decode
from psgrasp_training.export import sha256_bytes
from psgrasp_training.model import MLP_OUTPUTS
from psgrasp_training.train import train


def quiet(*_):
    pass


@pytest.fixture(scope="module")
def trained_run(box_dataset, tmp_path_factory):
    from conftest import tiny_config

    run = tmp_path_factory.mktemp("run")
    val = train(tiny_config(), box_dataset, run, export=True, log=quiet)
    return run, val


def test_train_writes_log_checkpoints_and_model(trained_run):
    run, val = trained_run
    rows = (run / "log.csv").read_text().strip().splitlines()
    assert rows[0].startswith("step,loss,label") and len(rows) == 11
    last = dict(zip(rows[0].split(","), rows[-1].split(",")))
    assert float(last["hit_rate"]) > 0.5 and float(last["points"]) > 0 and float(last["baseline"]) != 0
    assert (run / "checkpoints" / "step_0000005.pt").is_file() and load_checkpoint(run)["step"] == 10
    assert val["scenes"] == 1 and val["points"] > 0 and set(val["iou"]) == {"empty", "contact", "gripper"}
    assert 0 <= val["contact_recall"] <= 1 and val["contact_voxels_true"] > 0 and val["kappa_mean"] >= 25
    # ν's mean angle to all neighbour labels is at least its angle to the nearest one.
    assert val["baseline_mean_neighbour_angle_deg"] >= val["baseline_angle_error_deg"] - 1e-4
    assert 0 <= val["kappa_earned_above_floor"] <= 1 and val["kappa_earned_median"] >= 0
    bands = val["baseline_angle_error_by_neighbours"]
    # The bands split the labelled points: their counts add up, their weighted mean is the overall error.
    n_hit = sum(b["points"] for b in bands.values())
    assert n_hit == round(val["points"] * val["hit_rate"]) and n_hit > 0
    weighted = sum(b["points"] * b["mean_deg"] for b in bands.values()) / n_hit
    assert abs(weighted - val["baseline_angle_error_deg"]) < 1e-3 * max(1.0, weighted)
    assert -1 <= val["kappa_rank_correlation"] <= 1
    card = json.loads((run / "model" / "card.json").read_text())
    assert card["training"]["iterations"] == 10 and card["grid"]["dims"] == [16, 16, 16]
    # The training time over all sittings, as the final checkpoint has it, in core-hours too.
    time_rec = card["training"]["time"]
    elapsed = load_checkpoint(run)["elapsed_s"]
    assert time_rec["elapsed_s"] == pytest.approx(elapsed, abs=0.1) and elapsed > 0 and time_rec["threads"] == 1
    assert time_rec["cpu_hours"] == pytest.approx(time_rec["elapsed_s"] / 3600, abs=1e-3)
    assert card["validation"]["baseline_angle_error_deg"] == pytest.approx(val["baseline_angle_error_deg"])
    for key in ("unet", "mlp"):
        assert card["files"][key]["sha256"] == sha256_bytes((run / "model" / card["files"][key]["path"]).read_bytes())


def test_exported_graphs_match_pytorch_and_reference(trained_run, box_dataset, tmp_path):
    run, _ = trained_run
    out = tmp_path / "model"
    scene = box_dataset / "scene_000002.safetensors"
    assert main(["export", "--run", str(run), "--out", str(out), "--reference", str(scene),
                 "--contact-probability", "0.0"]) == 0
    card = json.loads((out / "card.json").read_text())
    ref = load_file(str(out / "reference.safetensors"))
    assert ref["points"].shape == (256, 3) and ref["features"].shape == (256, card["mlp"]["feature_dim"])

    unet = ort.InferenceSession(str(out / "unet.onnx"), providers=["CPUExecutionProvider"])
    names = [o.name for o in unet.get_outputs()]
    assert names == ["label_logits", "enc0", "enc1"]
    got = dict(zip(names, unet.run(None, {"normal_grid": ref["normal_grid"]})))
    for k in names:
        np.testing.assert_allclose(got[k], ref[k], atol=1e-5)
    mlp = ort.InferenceSession(str(out / "mlp.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in mlp.get_outputs()] == list(MLP_OUTPUTS)
    for n in (1, 7, 256):
        res = dict(zip(MLP_OUTPUTS, mlp.run(None, {"features": ref["features"][:n]})))
        for k in MLP_OUTPUTS:
            np.testing.assert_allclose(res[k], ref[k][:n], atol=1e-5)
    assert np.allclose(np.linalg.norm(ref["baseline"], axis=1), 1, atol=1e-5)
    assert (ref["kappa"] >= 25 - 1e-4).all() and (ref["kappa"] <= 100 + 1e-3).all()
    assert (ref["width"] > 0).all() and (ref["width"] < 0.08).all()

    # PyTorch model vs ONNX outputs, and decoding from the ONNX logits reproduces the reference.
    state = load_checkpoint(run)
    from psgrasp_training.model import GraspNet

    net = GraspNet(state["config"]).eval()
    net.load_state_dict(state["model"])
    with torch.no_grad():
        logits, _ = net.unet(torch.from_numpy(ref["normal_grid"]))
        np.testing.assert_allclose(logits.numpy(), got["label_logits"], atol=1e-5)
        mlp_out = {k: torch.from_numpy(v) for k, v in res.items()}
        dec = decode(class_probabilities(torch.from_numpy(got["label_logits"])), mlp_out,
                     torch.from_numpy(ref["points"]), [16 * 0.009] * 3, card["gripper"]["approach_depth_m"])
    np.testing.assert_allclose(dec.quality.numpy(), ref["quality"], atol=1e-5)
    np.testing.assert_allclose(dec.collision_scores.numpy(), ref["collision_scores"], atol=1e-5)


def test_same_seed_same_weights_and_exact_resume(box_dataset, tmp_path):
    from conftest import tiny_config

    cfg = lambda: tiny_config(iterations=6, checkpoint_every=0)  # noqa: E731
    train(cfg(), box_dataset, tmp_path / "a", export=False, log=quiet)
    train(cfg(), box_dataset, tmp_path / "b", export=False, log=quiet)
    train(cfg(), box_dataset, tmp_path / "c", export=False, log=quiet, stop_at=4)
    assert load_checkpoint(tmp_path / "c")["step"] == 4
    train(cfg(), box_dataset, tmp_path / "c", resume=True, export=False, log=quiet)
    a, b, c = (load_checkpoint(tmp_path / r)["model"] for r in "abc")
    for k in a:
        assert torch.equal(a[k], b[k]), k
        assert torch.equal(a[k], c[k]), k
    other = load_checkpoint(tmp_path / "a")
    assert other["step"] == 6
    # The log of the resumed run has one row per step.
    assert len((tmp_path / "c" / "log.csv").read_text().strip().splitlines()) == 7


def test_cli_reports_errors(tmp_path, capsys):
    assert main(["export", "--run", str(tmp_path / "missing"), "--out", str(tmp_path / "m")]) == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_an_8app_run_exports_as_the_1app_ablation_from_any_checkpoint(trained_run, tmp_path, capsys):
    run, _ = trained_run
    out = tmp_path / "w-kappa-1app"
    assert main(["export", "--run", str(run), "--out", str(out), "--checkpoint", "step_0000005.pt",
                 "--variant", "1app-kappa"]) == 0
    card = json.loads((out / "card.json").read_text())
    assert card["inference"]["single_approach"] is True and "1app-kappa" in card["name"]
    assert card["training"]["iterations"] == 5
    assert card["training"]["time"]["elapsed_s"] == pytest.approx(load_checkpoint(run, "step_0000005.pt")["elapsed_s"],
                                                                  abs=0.1)
    plain = json.loads((run / "model" / "card.json").read_text())
    assert plain["inference"]["single_approach"] is False
    # The cosine ablation is trained differently: an 8app run cannot stand in for it.
    from psgrasp_training.export import ExportError, export_run

    with pytest.raises(ExportError, match="cannot be exported as 1app-cosine"):
        export_run(run, tmp_path / "x", variant="1app-cosine", log=quiet)


def test_fitted_iterations_fill_the_budget_less_the_reserve():
    from psgrasp_training.train import fitted_iterations

    # 100 s budget, reserve 10 s, 20 s gone, 1 s per step: 70 more steps.
    assert fitted_iterations(10, 20.0, 1.0, 100.0, 10**6) == 80
    assert fitted_iterations(10, 20.0, 1.0, 100.0, 50) == 50  # never above the configured count
    assert fitted_iterations(10, 95.0, 1.0, 100.0, 10**6) == 11  # out of time: one more step
    # Long budgets reserve 5 %: 600 s → 30 s.
    assert fitted_iterations(0, 0.0, 0.5, 600.0, 10**6) == 1140


def test_budget_fit_probes_then_refits_once():
    from psgrasp_training.train import FIT_WARMUP_STEPS, BudgetFit

    fit = BudgetFit(minutes=1.0, probe_steps=4, start=0, cap=10**6)
    w = FIT_WARMUP_STEPS
    assert fit.after_step(w, 3.0) is None  # warm-up ends: the clock starts here
    assert all(fit.after_step(s, 3.0 + (s - w)) is None for s in range(w + 1, w + 4))
    n, rate = fit.after_step(w + 4, 7.0)  # 4 steps in 4 s
    assert rate == 1.0 and n == (w + 4) + int((60.0 - 10.0 - 7.0) / 1.0)
    assert fit.after_step(w + 5, 8.0) is None  # before 20 % of the budget (12 s)
    n, rate = fit.after_step(w + 10, 13.0)  # refit with all 10 timed steps
    assert rate == 1.0 and n == w + 10 + 37
    assert fit.after_step(w + 20, 30.0) is None  # only once


def test_a_budget_fitted_run_ends_its_schedule_with_the_budget(box_dataset, tmp_path):
    from conftest import tiny_config

    run = tmp_path / "fit"
    lines = []
    cfg = tiny_config(iterations=10**6, checkpoint_every=0, fit_minutes=0.25, fit_probe_steps=3)
    train(cfg, box_dataset, run, export=True, log=lines.append)
    assert any(line.startswith("fitted to 0.25 min") for line in lines), lines
    assert not any("wall-clock limit" in line for line in lines), lines
    iterations = json.loads((run / "config.json").read_text())["train"]["iterations"]
    assert 3 + 3 < iterations < 10**6  # past the warm-up and probe steps
    assert load_checkpoint(run)["step"] == iterations  # ended by its schedule, not the hard stop
    assert json.loads((run / "model" / "card.json").read_text())["training"]["iterations"] == iterations


def test_profile_times_every_phase_of_the_steps_training_runs(box_dataset):
    from conftest import tiny_config

    from psgrasp_training.profile import profile_steps

    lines = []
    cfg = tiny_config(iterations=6, checkpoint_every=0, mlp_warmup_iterations=0)
    means = profile_steps(cfg, box_dataset, steps=2, start_step=0, log=lines.append)
    assert list(means) == ["scene load + flip", "unet forward", "label loss", "contact points", "grasp targets",
                           "feature sampling", "mlp forward", "grasp loss", "backward", "optimiser step"]
    assert all(v > 0 for v in means.values())
    table = "\n".join(lines)
    assert "| backward |" in table and "steps/s" in table
    # Before the MLP warm-up ends only the label phases run.
    early = profile_steps(tiny_config(iterations=6, mlp_warmup_iterations=100), box_dataset, steps=1, start_step=0,
                          log=lambda _: None)
    assert "mlp forward" not in early and "unet forward" in early


def test_a_run_resumed_in_a_new_process_equals_an_uninterrupted_one(box_dataset, tmp_path):
    import os
    import subprocess
    import sys

    config = Path(__file__).resolve().parents[1] / "configs" / "tiny.toml"

    def cli(*args):
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        subprocess.run([sys.executable, "-m", "psgrasp_training", "train", "--config", str(config), "--data",
                        str(box_dataset), "--iterations", "8", "--no-export", *args],
                       check=True, capture_output=True, cwd=Path(__file__).resolve().parents[1], env=env)

    cli("--out", str(tmp_path / "whole"))
    cli("--out", str(tmp_path / "parts"), "--stop-at", "3")
    assert load_checkpoint(tmp_path / "parts")["step"] == 3
    cli("--out", str(tmp_path / "parts"), "--stop-at", "6", "--resume")
    cli("--out", str(tmp_path / "parts"), "--resume")
    whole, parts = (load_checkpoint(tmp_path / r) for r in ("whole", "parts"))
    assert whole["step"] == parts["step"] == 8
    for k in whole["model"]:
        assert torch.equal(whole["model"][k], parts["model"][k]), k
    for a, b in zip(whole["optimizer"]["state"].values(), parts["optimizer"]["state"].values()):
        assert torch.equal(a["exp_avg"], b["exp_avg"]) and torch.equal(a["exp_avg_sq"], b["exp_avg_sq"])


def test_a_run_trained_on_crops_validates_and_exports_the_whole_grid(box_dataset, tmp_path):
    from conftest import tiny_config

    cfg = tiny_config(iterations=4, checkpoint_every=0, mlp_warmup_iterations=1)
    cfg.data.crop = [8, 8, 8]
    validation = train(cfg, box_dataset, tmp_path / "run", log=quiet)
    assert validation["scenes"] >= 1 and validation["points"] > 0
    card = json.loads((tmp_path / "run" / "model" / "card.json").read_text())
    assert card["grid"]["dims"] == [16, 16, 16]
    # The exported U-Net runs on the whole grid and equals the trained weights there (the export
    # checks ONNX Runtime against PyTorch on a whole validation scene; here once more by hand).
    net = load_checkpoint(tmp_path / "run")
    from psgrasp_training.model import GraspNet

    model = GraspNet(net["config"])
    model.load_state_dict(net["model"])
    model.eval()
    x = torch.from_numpy(np.random.default_rng(0).standard_normal((1, 3, 16, 16, 16)).astype(np.float32))
    with torch.no_grad():
        logits, _ = model.unet(x)
    sess = ort.InferenceSession(str(tmp_path / "run" / "model" / "unet.onnx"))
    got = sess.run(None, {sess.get_inputs()[0].name: x.numpy()})[0]
    np.testing.assert_allclose(got, logits.numpy(), atol=1e-4)


def test_a_fine_tune_starts_from_the_checkpoint_weights_and_refuses_another_model(box_dataset, tmp_path):
    from conftest import tiny_config

    from psgrasp_training.train import RunError

    train(tiny_config(iterations=4, checkpoint_every=0), box_dataset, tmp_path / "parent", export=False, log=quiet)
    parent = load_checkpoint(tmp_path / "parent")
    # Zero fine-tune steps: the run's weights are the parent's; its time continues the parent's.
    cfg = tiny_config(iterations=0, checkpoint_every=0)
    cfg.train.init_weights = str(tmp_path / "parent" / "checkpoints" / "latest.pt")
    train(cfg, box_dataset, tmp_path / "tune0", export=False, log=quiet)
    tuned = load_checkpoint(tmp_path / "tune0")
    for k in parent["model"]:
        assert torch.equal(parent["model"][k], tuned["model"][k]), k
    assert tuned["elapsed_s"] >= parent["elapsed_s"]
    # With steps it moves away from them, with a fresh schedule (step 0 learning rate).
    cfg.train.iterations = 2
    train(cfg, box_dataset, tmp_path / "tune2", export=False, log=quiet)
    moved = load_checkpoint(tmp_path / "tune2")["model"]
    assert any(not torch.equal(parent["model"][k], moved[k]) for k in moved if moved[k].is_floating_point())
    # Another model shape is refused, naming the setting.
    other = tiny_config(iterations=1, checkpoint_every=0)
    other.model.base_channels += 2
    other.train.init_weights = cfg.train.init_weights
    with pytest.raises(RunError, match="init_weights"):
        train(other, box_dataset, tmp_path / "other", export=False, log=quiet)
