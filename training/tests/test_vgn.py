"""The VGN-style baseline: targets on hand-made scenes, the loss, training, export and the CLI."""

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from safetensors.numpy import load_file

from psgrasp_training.__main__ import main
from psgrasp_training.checkpoint import load_checkpoint
from psgrasp_training.config import ConfigError, config_from_dict
from psgrasp_training.data import Scene, read_scene
from psgrasp_training.decode import approach_vectors
from psgrasp_training.export import sha256_bytes
from psgrasp_training.vgn import VGN_OUTPUTS, orientation, train_vgn, vgn_loss, vgn_targets

V = 0.009
DIMS = [16, 16, 16]


def quiet(*_):
    pass


def vgn_config(**train):
    t = {"iterations": 8, "checkpoint_every": 4, "log_every": 4, "threads": 1}
    t.update(train)
    return config_from_dict({"variant": "vgn", "seed": 5, "model": {"base_channels": 4},
                             "grid": {"dims": DIMS}, "data": {"val_scenes": 1, "cache": True}, "train": t})


def scene_with(grasps):
    """A 16³ scene holding the given (contact, baseline, width, quality, free approach indices)."""
    n = len(grasps)
    free = torch.zeros(n, 18)
    for g, (_, _, _, _, idx) in enumerate(grasps):
        free[g, list(idx)] = 1.0
    return Scene(normals=torch.zeros(3, *DIMS), labels=torch.zeros(DIMS, dtype=torch.long),
                 contact=torch.tensor([g[0] for g in grasps], dtype=torch.float32),
                 baseline=torch.tensor([g[1] for g in grasps], dtype=torch.float32),
                 width=torch.tensor([g[2] for g in grasps], dtype=torch.float32),
                 quality=torch.tensor([g[3] for g in grasps], dtype=torch.float32),
                 collision_free=free, voxel_size_m=V)


def voxel_of(contact, baseline, width):
    c = np.array(contact) + np.array(baseline) * width / 2
    return tuple(int(x) for x in np.floor(c / V))


def test_targets_keep_the_best_labelled_grasp_per_voxel():
    x = [1.0, 0.0, 0.0]
    grasps = [
        ([0.050, 0.050, 0.050], x, 0.030, 0.90, [3, 12]),   # A: loses to B (same voxel, lower quality)
        ([0.050, 0.050, 0.050], x, 0.030, 0.95, [0]),       # B: best quality in its voxel
        ([0.100, 0.100, 0.060], x, 0.020, 0.40, range(18)),  # C: quality ≤ 0.5, not a target
        ([0.100, 0.030, 0.060], x, 0.020, 0.80, []),        # D: no collision-free approach
        ([0.030, 0.110, 0.040], [0.0, 1.0, 0.0], 0.010, 0.70, [7, 9]),  # E: approach 9 is nearer vertical
    ]
    tg = vgn_targets(scene_with(grasps))
    vb, ve = voxel_of(*grasps[1][:3]), voxel_of(*grasps[4][:3])
    assert vb != ve
    assert set(map(tuple, tg["positive"].nonzero().tolist())) == {vb, ve}
    b = torch.tensor(x)
    assert torch.allclose(tg["baseline"][(slice(None), *vb)], b)
    assert torch.allclose(tg["approach"][(slice(None), *vb)], approach_vectors(b.unsqueeze(0))[0, 0])
    assert tg["width"][vb].item() == pytest.approx(0.030)
    assert torch.allclose(tg["approach"][(slice(None), *ve)], approach_vectors(torch.tensor([[0.0, 1.0, 0.0]]))[0, 9])
    assert tg["width"][ve].item() == pytest.approx(0.010)
    assert tg["width"].count_nonzero() == 2


def test_dilated_targets_spread_the_best_grasp_to_the_neighbourhood():
    x = [1.0, 0.0, 0.0]
    grasps = [([0.050, 0.050, 0.050], x, 0.030, 0.90, [3]),    # centre voxel (7, 5, 5)
              ([0.068, 0.050, 0.050], x, 0.030, 0.95, [0])]    # centre voxel (9, 5, 5): better
    va, vb = voxel_of(*grasps[0][:3]), voxel_of(*grasps[1][:3])
    assert (va, vb) == ((7, 5, 5), (9, 5, 5))
    tg = vgn_targets(scene_with(grasps), dilate=1)
    assert int(tg["positive"].sum()) == 5 * 3 * 3  # x 6..10, y 4..6, z 4..6
    b = torch.tensor(x).unsqueeze(0)
    a0, a3 = approach_vectors(b)[0, 0], approach_vectors(b)[0, 3]
    assert torch.allclose(tg["approach"][:, 8, 5, 5], a0)  # shared neighbour: the better grasp
    assert torch.allclose(tg["approach"][:, 6, 4, 6], a3)  # only near the first grasp
    assert torch.allclose(tg["approach"][:, 10, 6, 4], a0)
    assert vgn_targets(scene_with(grasps))["positive"].nonzero().tolist() == sorted([list(va), list(vb)])


def test_targets_of_a_scene_without_grasps_are_all_negative():
    tg = vgn_targets(scene_with([([0.05, 0.05, 0.05], [1.0, 0.0, 0.0], 0.03, 0.3, [4])]))
    assert not tg["positive"].any() and tg["width"].abs().sum() == 0


def test_loss_is_symmetric_in_the_baseline_sign_and_zero_for_a_perfect_orientation():
    grasps = [([0.050, 0.050, 0.050], [1.0, 0.0, 0.0], 0.036, 0.9, [8])]
    scene = scene_with(grasps)
    tg = vgn_targets(scene)
    pos = tg["positive"]
    out = {"quality_logit": torch.where(pos, 20.0, -20.0).reshape(1, 1, *DIMS),
           "baseline": tg["baseline"].unsqueeze(0).clone(), "approach": tg["approach"].unsqueeze(0).clone(),
           "width_vox": (tg["width"] / V).reshape(1, 1, *DIMS)}
    perfect = vgn_loss(out, tg, V)
    assert perfect["rotation"].item() == pytest.approx(0.0, abs=1e-6)
    assert perfect["width"].item() == pytest.approx(0.0, abs=1e-8)
    assert perfect["quality"].item() < 1e-6 and perfect["positives"] == 1
    flipped = dict(out, baseline=-out["baseline"])
    assert vgn_loss(flipped, tg, V)["rotation"].item() == pytest.approx(0.0, abs=1e-6)
    wrong = dict(out, approach=-out["approach"])
    assert vgn_loss(wrong, tg, V)["rotation"].item() == pytest.approx(2.0, abs=1e-5)


def test_orientation_is_unit_and_orthogonal():
    g = torch.Generator().manual_seed(0)
    b, a = orientation(torch.randn(1, 3, 4, 4, 4, generator=g), torch.randn(1, 3, 4, 4, 4, generator=g))
    assert torch.allclose(b.norm(dim=1), torch.ones(1, 4, 4, 4), atol=1e-5)
    assert torch.allclose(a.norm(dim=1), torch.ones(1, 4, 4, 4), atol=1e-5)
    assert (b * a).sum(1).abs().max() < 1e-5


def test_vgn_config_needs_grids_divisible_by_8():
    with pytest.raises(ConfigError, match="divisible by 8"):
        config_from_dict({"variant": "vgn", "model": {"levels": 1}, "grid": {"dims": [12, 16, 16]}})


@pytest.fixture(scope="module")
def vgn_run(box_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("vgn-run")
    val = train_vgn(vgn_config(), box_dataset, run, export=True, log=quiet)
    return run, val


def test_train_exports_a_checked_model_directory(vgn_run, box_dataset):
    run, val = vgn_run
    rows = (run / "log.csv").read_text().strip().splitlines()
    assert rows[0].startswith("step,loss,quality,rotation") and len(rows) == 9
    assert load_checkpoint(run)["step"] == 8 and (run / "checkpoints" / "step_0000004.pt").is_file()
    assert val["scenes"] == 1 and val["positives"] > 0
    card = json.loads((run / "model" / "card.json").read_text())
    assert card["format"] == "psgrasp-vgn-model" and card["variant"] == "vgn"
    assert card["grid"]["dims"] == DIMS and card["gripper"]["max_opening_m"] == pytest.approx(0.08)
    assert card["files"]["vgn"]["sha256"] == sha256_bytes((run / "model" / "vgn.onnx").read_bytes())
    ref = load_file(str(run / "model" / "reference.safetensors"))
    sess = ort.InferenceSession(str(run / "model" / "vgn.onnx"), providers=["CPUExecutionProvider"])
    assert [o.name for o in sess.get_outputs()] == list(VGN_OUTPUTS)
    got = dict(zip(VGN_OUTPUTS, sess.run(None, {"normal_grid": ref["normal_grid"]})))
    for name in VGN_OUTPUTS:
        assert np.abs(got[name] - ref[name]).max() < 1e-5, name
    q, b, a = got["quality"], got["baseline"], got["approach"]
    assert q.shape == (1, 1, *DIMS) and 0 <= q.min() and q.max() <= 1
    assert np.abs(np.linalg.norm(b, axis=1) - 1).max() < 1e-4 and np.abs((a * b).sum(1)).max() < 1e-4
    scene = read_scene(box_dataset / "scene_000002.safetensors")
    assert np.array_equal(ref["normal_grid"][0], scene.normals.numpy())


def test_cli_exports_a_vgn_run_only_as_vgn(vgn_run, tmp_path, capsys):
    run, _ = vgn_run
    assert main(["export", "--run", str(run), "--out", str(tmp_path / "m"), "--checkpoint", "step_0000004.pt"]) == 0
    assert json.loads((tmp_path / "m" / "card.json").read_text())["training"]["iterations"] == 4
    assert main(["export", "--run", str(run), "--out", str(tmp_path / "x"), "--variant", "8app"]) == 2
    assert "exports only as vgn" in capsys.readouterr().err


def test_same_seed_same_weights_and_the_quality_head_learns(box_dataset, tmp_path):
    a = train_vgn(vgn_config(iterations=30, checkpoint_every=0), box_dataset, tmp_path / "a", export=False, log=quiet)
    b = train_vgn(vgn_config(iterations=30, checkpoint_every=0), box_dataset, tmp_path / "b", export=False, log=quiet)
    wa, wb = load_checkpoint(tmp_path / "a")["model"], load_checkpoint(tmp_path / "b")["model"]
    assert all(torch.equal(wa[k], wb[k]) for k in wa) and a == b
    rows = [r.split(",") for r in (tmp_path / "a" / "log.csv").read_text().strip().splitlines()[1:]]
    quality = [float(r[2]) for r in rows]
    assert np.mean(quality[-5:]) < np.mean(quality[:5])


def test_negative_region_is_the_surface_band():
    from psgrasp_training.vgn import negative_region

    normals = torch.zeros(3, *DIMS)
    normals[2, 5, 6, 7] = 1.0
    band = negative_region(normals, 1)
    assert int(band.sum()) == 27 and band[4:7, 5:8, 6:9].all()
    assert int(negative_region(normals, 2).sum()) == 125
    assert negative_region(normals, 0).all()


def test_weighted_quality_loss_is_one_weighted_mean_over_the_region():
    grasps = [([0.050, 0.050, 0.050], [1.0, 0.0, 0.0], 0.036, 0.9, [8])]
    tg = vgn_targets(scene_with(grasps))
    out = {"quality_logit": torch.zeros(1, 1, *DIMS), "baseline": tg["baseline"].unsqueeze(0),
           "approach": tg["approach"].unsqueeze(0), "width_vox": (tg["width"] / V).reshape(1, 1, *DIMS)}
    region = torch.zeros(DIMS, dtype=torch.bool)
    region[0:2, 0:2, 0:2] = True  # 8 negatives
    out["quality_logit"][0, 0][tg["positive"]] = 2.0
    bce_pos = float(torch.nn.functional.softplus(torch.tensor(-2.0)))
    bce_neg = float(torch.nn.functional.softplus(torch.tensor(0.0)))
    weighted = vgn_loss(out, tg, V, region, positive_weight=4.0)["quality"].item()
    assert weighted == pytest.approx((4 * bce_pos + 8 * bce_neg) / (4 + 8), rel=1e-5)
    balanced = vgn_loss(out, tg, V, region)["quality"].item()
    assert balanced == pytest.approx(bce_pos + bce_neg, rel=1e-5)
