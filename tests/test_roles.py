"""Agent roles as model inputs (ModelConfig.num_roles): the one-hot columns are the only
difference from a role-free model, the number comes from the training data, and a model that
reads roles refuses data without them."""

from __future__ import annotations

import math

import pytest
import torch

from predictor.config import ROLES_FROM_DATA, ModelConfig, resolve_roles
from predictor.model import SmoothAttentionPredictor
from predictor.presets import make_configs

torch.set_num_threads(1)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
AGENT = {"frame": "agent", "standardise": True, "edge_velocity": True}


def moving_scene(batch: int = 2, steps: int = 9, agents: int = 4):
    gen = torch.Generator().manual_seed(0)
    velocity = 1.0 + torch.rand(batch, 1, agents, 2, generator=gen)
    bend = 0.05 * torch.randn(batch, 1, agents, 2, generator=gen)
    t = torch.arange(steps, dtype=torch.float32).view(1, steps, 1, 1)
    positions = 10 * torch.rand(batch, 1, agents, 2, generator=gen) + velocity * t + bend * t**2
    return positions, torch.ones(batch, steps, agents, dtype=torch.bool)


def randomise(model: SmoothAttentionPredictor, seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for param in model.parameters():
            param.copy_(0.3 * torch.randn(param.shape, generator=gen))


def test_role_columns_are_the_only_difference_from_a_role_free_model():
    positions, valid = moving_scene()
    roles = torch.tensor([[0, 1, 2, 2], [1, 0, 2, 2]])
    plain = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT))
    with_roles = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, num_roles=3))
    for model in (plain, with_roles):
        model.fit_normalisation(positions, valid, 4)
    randomise(plain, seed=1)
    state = plain.state_dict()
    for name in ("f_embed.0.weight", "f_self.0.weight"):  # role columns zero: roles unused
        width = state[name].shape[1]
        state[name] = torch.cat([state[name], torch.zeros(state[name].shape[0], 3)], 1)
        assert with_roles.state_dict()[name].shape[1] == width + 3
    with_roles.load_state_dict(state)
    expected = plain.predict(positions, valid, 4).rollout.mean
    got = with_roles.predict(positions, valid, 4, roles=roles).rollout.mean
    torch.testing.assert_close(got, expected)
    with torch.no_grad():
        with_roles.encoder.f_self[0].weight[:, -3:].normal_()  # now the roles matter
    moved = with_roles.predict(positions, valid, 4, roles=roles).rollout.mean
    swapped = with_roles.predict(positions, valid, 4, roles=roles.flip(-1)).rollout.mean
    assert (moved - expected).abs().max() > 1e-3
    assert (moved - swapped).abs().max() > 1e-3


def test_a_role_model_refuses_missing_or_unknown_roles():
    positions, valid = moving_scene()
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, num_roles=3))
    model.fit_normalisation(positions, valid, 4)
    with pytest.raises(ValueError, match="reads agent roles"):
        model.predict(positions, valid, 4)
    with pytest.raises(ValueError, match=r"roles must be in \[0, 2\]"):
        model.predict(positions, valid, 4, roles=torch.full((2, 4), 3))


def test_roles_from_data_resolve_to_the_number_of_role_names():
    config = ModelConfig(**SMALL, **AGENT, num_roles=ROLES_FROM_DATA)
    assert resolve_roles(config, ("a", "b", "c")).num_roles == 3
    assert resolve_roles(ModelConfig(**SMALL), ("a", "b")).num_roles == 0
    with pytest.raises(ValueError, match="reads 3 agent roles; the data has 2"):
        resolve_roles(ModelConfig(**SMALL, num_roles=3), ("a", "b"))
    with pytest.raises(ValueError, match="resolved first"):
        SmoothAttentionPredictor(config)
    with pytest.raises(ValueError, match="num_roles must be >= -1"):
        ModelConfig(num_roles=-2)


def test_a_training_run_stores_the_resolved_role_count(dataset_file, tmp_path):
    from predictor.checkpoints import load_model
    from predictor.evaluation import evaluate_run
    from predictor.training import train

    overrides = {**SMALL, "num_roles": ROLES_FROM_DATA}
    model_cfg, train_cfg = make_configs("ours", overrides, preset="agent", epochs=1)
    train(dataset_file, model_cfg, train_cfg, tmp_path / "run", progress=False)
    model, checkpoint = load_model(tmp_path / "run" / "best.pt")
    assert model.config.num_roles == 3  # conftest's datasets name three roles
    assert checkpoint["model_config"]["num_roles"] == 3
    scores = evaluate_run(tmp_path / "run", dataset_file).scores
    assert scores["main_agents"]["overall"]["ade"] > 0


def test_evaluation_refuses_data_with_other_role_names(make_dataset_file, tmp_path):
    import h5py

    from predictor.evaluation import evaluate_run
    from predictor.forecasting import EvaluationError
    from predictor.training import train

    train_file = make_dataset_file("train.h5")
    other = make_dataset_file("other.h5")
    with h5py.File(other, "r+") as file:  # same shapes, roles named differently
        names = [name for name in file.attrs if "role" in name]
        assert names, "conftest datasets carry role names"
        for name in names:
            value = file.attrs[name]
            file.attrs[name] = value.replace("main", "lead") if isinstance(value, str) else value
    model_cfg, train_cfg = make_configs("ours", {**SMALL, "num_roles": -1}, "agent", epochs=1)
    train(train_file, model_cfg, train_cfg, tmp_path / "run", progress=False)
    with pytest.raises(EvaluationError, match="reads agent roles"):
        evaluate_run(tmp_path / "run", other)


def test_without_role_input_the_network_ignores_roles_but_the_highway_reads_them():
    positions, valid = moving_scene(batch=2, steps=12)
    roles = torch.tensor([[0, 1, 2, 2], [1, 0, 2, 2]])
    swapped = torch.tensor([[1, 0, 2, 2], [0, 1, 2, 2]])
    anchored = {**AGENT, "offset_scale": "deviation", "rollout_prior": "anchored"}
    outputs = {}
    for role_input in (True, False):
        config = ModelConfig(**SMALL, **anchored, num_roles=3, role_input=role_input)
        model = SmoothAttentionPredictor(config)
        randomise(model, seed=2)
        columns = 2 + (3 if role_input else 0)
        assert model.encoder.f_embed[0].in_features == columns
        outputs[role_input] = [
            model.predict(positions, valid, 6, roles=r).rollout.mean for r in (roles, swapped)
        ]
    assert (outputs[True][0] - outputs[True][1]).abs().max() > 1e-4  # roles are inputs
    torch.testing.assert_close(outputs[False][0], outputs[False][1])  # roles read by nothing
    config = ModelConfig(**SMALL, **anchored, num_roles=3, role_input=False, highway_steps=3)
    model = SmoothAttentionPredictor(config)
    randomise(model, seed=2)
    with torch.no_grad():  # a different highway map per role, its output range left open
        highway = model.highway
        highway.highway_weight.copy_(0.1 * torch.randn(highway.highway_weight.shape))
        highway.highway_low.fill_(-math.inf)
        highway.highway_high.fill_(math.inf)
    out = [model.predict(positions, valid, 6, roles=r).rollout.mean for r in (roles, swapped)]
    assert (out[0] - out[1]).abs().max() > 1e-4  # the highway still picks its map by role
