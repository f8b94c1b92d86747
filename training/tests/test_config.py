from pathlib import Path

import pytest

from psgrasp_training.config import ConfigError, config_from_dict, load_config

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "configs").glob("*.toml"))


def test_shipped_configs_load():
    names = {p.stem for p in CONFIGS}
    assert {"tiny", "cpu", "gpu", "ablation-1app-kappa", "ablation-1app-cosine"} <= names
    for path in CONFIGS:
        cfg = load_config(path)
        assert cfg.feature_dim() == sum(cfg.model.base_channels * 2**i for i in range(cfg.model.levels))
    assert load_config(CONFIGS[0].with_name("ablation-1app-cosine.toml")).kappa_learned is False
    assert load_config(CONFIGS[0].with_name("ablation-1app-kappa.toml")).single_approach is True


@pytest.mark.parametrize("data,match", [
    ({"modle": {}}, "unknown key"),
    ({"model": {"levels": "4"}}, "model.levels: expected an integer"),
    ({"variant": "2app"}, "variant"),
    ({"model": {"levels": 8}}, "divisible"),
    ({"contacts": {"neighbour_radius_m": 0.02}}, "neighbour_radius_m"),
    ({"loss": {"class_weights": [1, 2]}}, "class_weights"),
])
def test_bad_configs_are_refused(data, match):
    with pytest.raises(ConfigError, match=match):
        config_from_dict(data)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_config_extends_its_base_key_by_key(tmp_path):
    _write(tmp_path / "base.toml", 'seed = 3\n[model]\nbase_channels = 16\nlevels = 3\n'
           '[train]\niterations = 500\nlr = 1e-3\n')
    _write(tmp_path / "middle.toml", 'extends = "base.toml"\n[train]\nlr = 2e-4\n')
    child = _write(tmp_path / "child.toml", 'extends = "middle.toml"\nvariant = "1app-cosine"\n'
                   '[model]\nlevels = 4\n')
    cfg = load_config(child)
    assert (cfg.seed, cfg.variant) == (3, "1app-cosine")
    assert (cfg.model.base_channels, cfg.model.levels) == (16, 4)   # table merged, not replaced
    assert (cfg.train.iterations, cfg.train.lr) == (500, 2e-4)       # the chain's nearest value wins
    base = load_config(tmp_path / "base.toml")
    assert (base.model.levels, base.train.lr, base.variant) == (3, 1e-3, "8app")


@pytest.mark.parametrize("files,match", [
    ({"a.toml": 'extends = "b.toml"\n', "b.toml": 'extends = "a.toml"\n'}, "cycle"),
    ({"a.toml": 'extends = "a.toml"\n'}, "cycle"),
    ({"a.toml": 'extends = "nowhere.toml"\n'}, "cannot read config .*nowhere.toml"),
    ({"a.toml": "extends = 3\n"}, "'extends' must be a file name"),
    ({"a.toml": 'extends = "b.toml"\n', "b.toml": "[modle]\n"}, "unknown key"),
])
def test_bad_extends_chains_are_refused(tmp_path, files, match):
    for name, text in files.items():
        _write(tmp_path / name, text)
    with pytest.raises(ConfigError, match=match):
        load_config(tmp_path / "a.toml")


def test_shipped_variants_state_only_what_they_change():
    by_name = {p.name: p for p in CONFIGS}
    paper_points = load_config(by_name["cpu-crop32-surface-ft-dense-paper-points.toml"])
    dense = load_config(by_name["cpu-crop32-surface-ft-dense.toml"])
    assert paper_points.contacts.uniform_points == 512 and dense.contacts.uniform_points != 512
    paper_points.contacts.uniform_points = dense.contacts.uniform_points
    assert paper_points == dense
