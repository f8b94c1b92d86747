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
