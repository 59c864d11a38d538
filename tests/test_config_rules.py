"""predictor.config's validation: every rule of ModelConfig and TrainConfig rejects one wrong
field with a message naming it, and the presets and defaults pass them all."""

from __future__ import annotations

import pytest

from predictor.config import VARIANTS, ModelConfig, TrainConfig
from predictor.presets import PRESETS, make_configs

AGENT = {"frame": "agent"}
ANCHORED = {**AGENT, "rollout_prior": "anchored"}
HIGHWAY = {**ANCHORED, "highway_steps": 12}


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"frame": "world"}, "ModelConfig.frame must be one of ('scene', 'agent'), got 'world'"),
        ({"neighbours": "ring"}, "ModelConfig.neighbours must be one of"),
        ({"attended_fit": "rows"}, "ModelConfig.attended_fit must be one of"),
        ({"embed_dim": 0}, "ModelConfig.embed_dim must be >= 1, got 0"),
        ({"chunk_steps": 0}, "ModelConfig.chunk_steps must be >= 1, got 0"),
        ({"step_scale_m": 0.0}, "ModelConfig.step_scale_m must be > 0, got 0.0"),
        ({"attention_gain": -1.0}, "ModelConfig.attention_gain must be > 0, got -1.0"),
        ({"init_std_m": 0.01, "min_std_m": 0.01}, "ModelConfig.init_std_m must be > min_std_m"),
        ({"num_roles": -2}, "ModelConfig.num_roles must be >= -1, got -2"),
        ({"neighbour_k": 0}, "ModelConfig.neighbour_k must be >= 1, got 0"),
        ({**HIGHWAY, "highway_steps": 1}, "ModelConfig.highway_steps must be 0 or >= 2, got 1"),
        ({**HIGHWAY, "highway_horizon": 0}, "ModelConfig.highway_horizon must be >= 1, got 0"),
        ({"standardise": True}, "ModelConfig.standardise needs frame='agent'"),
        ({"offset_scale": "deviation"}, "ModelConfig.offset_scale='deviation' needs frame='agent'"),
        (
            {**AGENT, "highway_steps": 12},
            "ModelConfig.highway_steps=12 needs rollout_prior='anchored'",
        ),
        ({"highway_attended": True}, "ModelConfig.highway_attended needs highway_steps"),
        ({**HIGHWAY, "attended_refit": True}, "ModelConfig.attended_refit needs highway_attended"),
        (
            {**HIGHWAY, "highway_attended": True, "attended_fit": "edges"},
            "ModelConfig.attended_fit='edges' needs attended_refit",
        ),
        (
            {
                **HIGHWAY,
                "highway_attended": True,
                "attended_refit": True,
                "attended_fit": "edge_relations",
            },
            "ModelConfig.attended_fit='edge_relations' needs highway_relation",
        ),
        ({"highway_zero_at_cv": True}, "ModelConfig.highway_zero_at_cv needs attended_refit"),
        ({"highway_min_std": 1e-4}, "ModelConfig.highway_min_std=0.0001 needs attended_refit"),
        ({"highway_min_std": -1.0}, "ModelConfig.highway_min_std must be >= 0, got -1.0"),
    ],
)
def test_each_model_rule_names_the_field_it_rejects(fields, message):
    with pytest.raises(ValueError) as raised:
        ModelConfig(**fields)
    assert str(raised.value).startswith(message), raised.value


@pytest.mark.parametrize(
    "fields, message",
    [
        (
            {"lr_schedule": "step"},
            "TrainConfig.lr_schedule must be one of ('constant', 'cosine'), got 'step'",
        ),
        ({"mean_loss": "l1"}, "TrainConfig.mean_loss must be one of"),
        ({"batch_size": 0}, "TrainConfig.batch_size must be >= 1, got 0"),
        ({"lr_final_ratio": 2.0}, "TrainConfig.lr_final_ratio must be in [0, 1], got 2.0"),
    ],
)
def test_each_train_rule_names_the_field_it_rejects(fields, message):
    with pytest.raises(ValueError) as raised:
        TrainConfig(**fields)
    assert str(raised.value).startswith(message), raised.value


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_defaults_and_presets_pass_every_rule(preset):
    ModelConfig(), TrainConfig()
    for variant in VARIANTS:
        model, train = make_configs(variant, preset=preset)
        assert (model.attention_mode, train.variant) == (VARIANTS[variant].attention_mode, variant)
