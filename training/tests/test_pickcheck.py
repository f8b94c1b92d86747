"""The pick check: matching picks against labels, and the selection rules it applies."""

import dataclasses
import math

import torch

from psgrasp_training.data import SceneDataset
from psgrasp_training.decode import approach_vectors
from psgrasp_training.model import GraspNet
from psgrasp_training.pickcheck import PickCheckConfig, pick_check, pick_matches, scene_candidates, scene_picks
from psgrasp_training.train import pick_check_run, train


def quiet(*_):
    pass


def _rotate_z(v: torch.Tensor, deg: float) -> torch.Tensor:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return torch.stack([c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]])


def _first_scene(box_dataset, tiny_cfg):
    cfg = tiny_cfg()
    ds = SceneDataset(box_dataset, cfg)
    return cfg, ds, ds.scene(ds.train_entries[0])


def test_a_labelled_grasp_matches_and_its_variations_do_not(box_dataset, tiny_cfg):
    _, _, scene = _first_scene(box_dataset, tiny_cfg)
    pc = PickCheckConfig()
    g = 0
    c, b, w = scene.contact[g], scene.baseline[g], scene.width[g]
    approaches = approach_vectors(b.to(torch.float64)).to(torch.float32)
    free = int(scene.collision_free[g].argmax())
    blocked = int((1 - scene.collision_free[g]).argmax())
    assert scene.collision_free[g, free] == 1 and scene.collision_free[g, blocked] == 0

    def match(point, baseline, width, approach):
        return pick_matches(scene, point[None], baseline[None], width[None], approach[None], pc)[0]

    assert match(c, b, w, approaches[free])
    # 5 mm off the contact and 10° off the baseline still match; 20 mm or 45° do not.
    assert match(c + torch.tensor([0.0, 0.005, 0.0]), _rotate_z(b, 10.0), w, approaches[free])
    assert not match(c - 0.02 * b, b, w, approaches[free])
    assert not match(c, _rotate_z(b, 45.0), w, approaches[free])
    # A width 20 mm off, an approach the labels mark as colliding: no match.
    assert not match(c, b, w + 0.02, approaches[free])
    assert not match(c, b, w, approaches[blocked])
    # A label that failed the physics check (kept with quality 0, `failed_labels = "zero_quality"`)
    # is not a good grasp to match.
    failed = dataclasses.replace(scene, quality=torch.zeros_like(scene.quality))
    assert not pick_matches(failed, c[None], b[None], w[None], approaches[free][None], pc)[0]


def test_picks_follow_the_selection_rules(box_dataset, tiny_cfg):
    cfg, _, scene = _first_scene(box_dataset, tiny_cfg)

    def picks(seed, pc):
        torch.manual_seed(seed)
        net = GraspNet(cfg).eval()
        with torch.no_grad():
            return scene_picks(net, scene.normals, scene.extent_m, scene.voxel_size_m, 0.0, 0.039, pc)

    # Untrained nets with every threshold open propose picks; they must be ordered by q, spaced by
    # the pick spacing, at most k, and approach within the tilt cone.
    cones_met = 0
    for seed in range(4):
        for tilt in (90.0, 60.0):
            pc = PickCheckConfig(k=3, min_quality=0.0, min_collision_score=0.0, pick_spacing_m=0.02,
                                 max_approach_tilt_deg=tilt)
            points, baselines, widths, approaches, q = picks(seed, pc)
            assert len(points) <= 3
            if tilt == 90.0:
                assert len(points) >= 1
            cones_met += int(tilt == 60.0 and len(points) > 0)
            assert torch.all(q[:-1] >= q[1:])
            tcp = points + 0.5 * widths[:, None] * baselines
            for i in range(len(tcp)):
                for j in range(i):
                    assert float((tcp[i] - tcp[j]).norm()) >= 0.02
            assert torch.all(-approaches[:, 2] >= math.cos(math.radians(tilt)) - 1e-6)
    assert cones_met >= 1
    # A quality threshold above anything a softmax product reaches leaves no pick.
    assert len(picks(0, PickCheckConfig(min_quality=1.01, max_approach_tilt_deg=90.0))[0]) == 0


def test_candidates_from_a_precomputed_unet_pass_equal_those_computed_inside(box_dataset, tiny_cfg):
    # Validation runs the U-Net once per scene and hands its output to the pick check.
    cfg, _, scene = _first_scene(box_dataset, tiny_cfg)
    torch.manual_seed(1)
    net = GraspNet(cfg).eval()
    pc = PickCheckConfig(min_quality=0.0, min_collision_score=0.0, max_approach_tilt_deg=90.0)
    args = (net, scene.normals, scene.extent_m, scene.voxel_size_m, 0.0, 0.039, pc)
    with torch.no_grad():
        inside = scene_candidates(*args)
        given = scene_candidates(*args, unet_out=net.unet(scene.normals.unsqueeze(0)))
    assert len(inside) > 0
    for a, b in ((inside.points, given.points), (inside.baselines, given.baselines), (inside.quality, given.quality),
                 (inside.approaches, given.approaches), (inside.widths, given.widths)):
        assert torch.equal(a, b)


def test_pick_check_reports_every_group_and_runs_on_checkpoints(box_dataset, tiny_cfg, tmp_path):
    run = tmp_path / "run"
    cfg = tiny_cfg()
    val = train(cfg, box_dataset, run, export=False, log=quiet)
    # Validation carries the pick check; the held-out box scenes hold one object each: "easy".
    assert set(val["picks"]) == {"easy", "all"}
    assert val["picks"]["all"]["scenes"] == 1
    for v in val["picks"].values():
        assert 0.0 <= v["precision_at_k"] <= 1.0 and 0.0 <= v["no_pick"] <= 1.0
    results = pick_check_run(run, box_dataset, ["all"], log=quiet)
    assert sorted(results) == ["step_0000005.pt", "step_0000010.pt"]
    assert results["step_0000010.pt"]["all"] == val["picks"]["all"]
    # Same weights, same figures: the check is deterministic.
    ds = SceneDataset(box_dataset, cfg)
    net = GraspNet(cfg)
    from psgrasp_training.checkpoint import load_checkpoint

    net.load_state_dict(load_checkpoint(run, "step_0000010.pt")["model"])
    state = load_checkpoint(run, "step_0000010.pt")
    assert pick_check(net, ds, state["config"]) == {k: v for k, v in results["step_0000010.pt"].items() if k != "step"}


def test_grasp_objects_are_read_and_stay_aligned_through_crops(box_dataset, tiny_cfg):
    from psgrasp_training.data import crop_scene
    from psgrasp_training.pickcheck import matched_labels

    _, _, scene = _first_scene(box_dataset, tiny_cfg)
    assert scene.object is not None and scene.object.shape == scene.width.shape
    # Tag every grasp with its own index so that alignment is visible after the crop.
    tagged = type(scene)(**{**scene.__dict__, "object": torch.arange(len(scene.width))})
    cropped = crop_scene(tagged, [0, 0, 0], [8, 16, 16])
    assert 0 < len(cropped.object) < len(tagged.object)
    origin = torch.zeros(3)
    for i, tag in enumerate(cropped.object.tolist()):
        assert torch.allclose(cropped.contact[i] + origin, tagged.contact[tag])
        assert torch.equal(cropped.baseline[i], tagged.baseline[tag])
    # A pick exactly at a label matches a label near it, whose object the pick is credited to.
    g = 3
    free = int(tagged.collision_free[g].argmax())
    approach = approach_vectors(tagged.baseline[g].to(torch.float64)).to(torch.float32)[free]
    m = matched_labels(tagged, tagged.contact[g:g + 1], tagged.baseline[g:g + 1], tagged.width[g:g + 1],
                       approach[None], PickCheckConfig())
    assert int(m[0]) >= 0
    assert float((tagged.contact[int(m[0])] - tagged.contact[g]).norm()) <= PickCheckConfig().match_radius_m
