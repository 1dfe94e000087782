"""The one configuration module: the default preset is TrainConfig(), presets are data."""

import json

import pytest
import torch

from evsplat import config
from evsplat.config import PRESETS, TrainConfig, load_config, preset
from evsplat.errors import EvsplatError
from evsplat.train.schedule import decay_learning_rates


def test_the_default_preset_is_the_dataclass_default():
    assert preset("default") == TrainConfig()


def test_the_paper_preset_has_the_papers_schedule_and_deformable_3dgs_mlp():
    cfg = preset("paper")
    assert cfg.schedule.iterations == 30_000 and cfg.schedule.warmup_end == 3000
    assert cfg.schedule.refine_start == 20_000
    assert (cfg.model.mlp_width, cfg.model.mlp_depth, cfg.model.mlp_skip) == (256, 8, 4)
    assert (cfg.model.pe_x, cfg.model.pe_t) == (10, 6)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_round_trips_through_a_runs_config_json(name, tmp_path):
    cfg = preset(name)
    assert cfg.preset == name
    path = tmp_path / "config.json"
    path.write_text(json.dumps(cfg.to_dict()))
    assert load_config(path).to_dict() == json.loads(json.dumps(cfg.to_dict()))


def test_a_misspelt_preset_setting_and_an_unknown_preset_are_errors(monkeypatch):
    monkeypatch.setitem(PRESETS, "typo", {"model": {"mlp_widht": 3}})
    with pytest.raises(KeyError, match="mlp_widht"):
        preset("typo")
    with pytest.raises(EvsplatError, match="unknown preset 'huge'; choose one of"):
        preset("huge")


def test_a_config_saved_before_the_mover_existed_trains_without_it():
    d = TrainConfig().to_dict()
    del d["mover"]
    assert TrainConfig.from_dict(d).mover == config.MoverConfig(enabled=False)


def test_a_config_saved_with_a_fixed_mlp_rate_horizon_keeps_its_decay():
    """Runs saved before 30a96a3 (2026-11-26) give the MLP rate's decay in iterations; read
    back, the decay spans the same iterations as a fraction of their run."""
    d = TrainConfig().to_dict()
    d["schedule"]["iterations"] = 4000
    del d["model"]["mlp_lr_span"]
    d["model"]["mlp_lr_horizon"] = 40_000
    assert TrainConfig.from_dict(d).model.mlp_lr_span == pytest.approx(10.0)


def test_the_mlp_rate_decays_exponentially_over_its_span_of_the_run():
    cfg = preset("tiny")
    mlp = torch.optim.Adam([torch.zeros(1, requires_grad=True)], lr=1.0)
    gauss = torch.optim.Adam([{"params": [torch.zeros(1, requires_grad=True)], "name": "means"}])
    mc, n = cfg.model, cfg.schedule.iterations
    for it in (0, n // 2, n):
        decay_learning_rates(gauss, mlp, cfg, 1.0, it)
        expected = mc.mlp_lr * (mc.mlp_lr_final / mc.mlp_lr) ** (it / (mc.mlp_lr_span * n))
        assert mlp.param_groups[0]["lr"] == pytest.approx(expected)
