"""Checkpoints written before the predictor was composed of parts (tests/data/old_checkpoints,
made by its make_old_checkpoints.py with the mixin-chain model) load and predict as they did,
and today's models have the old state-dict names, shapes and parameter order (which an old
run's optimizer state and the per-group gradient clipping follow)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from predictor.checkpoints import load_model
from predictor.config import resolve_roles
from predictor.model import SmoothAttentionPredictor
from predictor.presets import make_configs
from predictor.run_state import make_optimizer
from predictor.stored_config import train_config_from_dict

OLD = Path(__file__).parent / "data" / "old_checkpoints"
TINY = {"embed_dim": 4, "edge_hidden": 4, "node_hidden": 6, "attn_dim": 2}
ROLE_NAMES = ("main_green", "main_brown", "distractor")
# float rounding of another CPU's vector instructions over a 45-step rollout; a changed
# computation moves the predictions by orders of magnitude more
TOLERANCE = {"rtol": 1e-4, "atol": 1e-4}


@pytest.fixture(scope="module")
def fixed() -> dict:
    return torch.load(OLD / "predictions.pt", weights_only=True)


@pytest.mark.parametrize("preset", ["paper", "agent"])
def test_an_old_checkpoint_predicts_what_it_did(fixed, preset):
    model, checkpoint = load_model(OLD / f"{preset}.pt")
    assert checkpoint["preset"] == preset
    out = model.predict(
        fixed["positions"], fixed["valid"], fixed["num_observed"], roles=fixed["roles"]
    )
    expected = fixed[preset]
    torch.testing.assert_close(out.rollout.mean, expected["rollout_mean"], **TOLERANCE)
    torch.testing.assert_close(out.rollout.tril, expected["rollout_tril"], **TOLERANCE)
    torch.testing.assert_close(out.one_step.mean, expected["one_step_mean"], **TOLERANCE)
    torch.testing.assert_close(out.attention[:, :, :2], expected["attention"], **TOLERANCE)
    rollout_attention = out.rollout_attention[:, :, :2]
    torch.testing.assert_close(rollout_attention, expected["rollout_attention"], **TOLERANCE)


@pytest.mark.parametrize("preset", ["paper", "agent"])
def test_an_old_runs_optimizer_state_fits_the_parameters_in_order(preset):
    """Adam's state is stored per parameter index: each index must hold the same tensor."""
    model, checkpoint = load_model(OLD / f"{preset}.pt")
    optimizer = make_optimizer(model, train_config_from_dict(checkpoint["train_config"]))
    optimizer.load_state_dict(checkpoint["optimizer_state"])
    parameters = list(model.parameters())
    assert len(optimizer.state) == len(parameters)
    for parameter in parameters:
        assert optimizer.state[parameter]["exp_avg"].shape == parameter.shape


def checkpoint_names_of_parameters(model: torch.nn.Module) -> list[str]:
    """The state-dict (checkpoint) name of each parameter, in the model's parameter order."""
    name_of = {id(value): name for name, value in model.state_dict(keep_vars=True).items()}
    return [name_of[id(parameter)] for parameter in model.parameters()]


@pytest.mark.parametrize("name", sorted(json.loads((OLD / "state_layout.json").read_text())))
def test_a_model_has_the_old_state_names_shapes_and_parameter_order(name):
    stored = json.loads((OLD / "state_layout.json").read_text())[name]
    model_cfg, _ = make_configs(
        stored["variant"], {**TINY, **stored["overrides"]}, preset=stored["preset"]
    )
    model = SmoothAttentionPredictor(resolve_roles(model_cfg, ROLE_NAMES))
    state = sorted([key, list(value.shape)] for key, value in model.state_dict().items())
    assert state == sorted(stored["state"])
    assert checkpoint_names_of_parameters(model) == stored["parameters"]
    model.load_state_dict(model.state_dict())  # what it writes, it reads
