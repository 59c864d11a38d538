"""The agent-centric model options (frame="agent"): equivariance, fitted scales, the output's
covariance rotation, and the loss and schedule options that come with the "agent" preset."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from predictor.agent_frame import agent_frames, rotate, rotate_tril
from predictor.config import ModelConfig, TrainConfig, resolve_roles
from predictor.losses import LossWeights, compute_loss
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import Gaussian2D, ModelOutput
from predictor.presets import PRESETS, make_configs
from predictor.training import learning_rate

torch.set_num_threads(1)
torch.set_default_dtype(torch.float32)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
AGENT = {"frame": "agent", "standardise": True, "edge_velocity": True}


def curved_scene(batch: int = 2, steps: int = 10, agents: int = 4, seed: int = 0):
    """Agents on arcs of random radius and speed (so velocities and their changes are nonzero)."""
    gen = torch.Generator().manual_seed(seed)
    start = torch.rand(batch, 1, agents, 2, generator=gen) * 30.0
    speed = 1.0 + torch.rand(batch, 1, agents, 1, generator=gen)
    turn = 0.05 * (torch.rand(batch, 1, agents, 1, generator=gen) - 0.5)
    heading0 = 2 * math.pi * torch.rand(batch, 1, agents, 1, generator=gen)
    t = torch.arange(steps, dtype=torch.float32).view(1, steps, 1, 1)
    heading = heading0 + turn * t
    step = speed * torch.cat([heading.cos(), heading.sin()], -1)  # (B, T, N, 2)
    positions = start + torch.cumsum(step, 1)
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    return positions, valid


def trained_looking(model: SmoothAttentionPredictor, seed: int = 1) -> SmoothAttentionPredictor:
    """Give the zero-initialised output layer random weights, so outputs depend on inputs."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        weight = model.head.f_pred.weight
        weight.copy_(0.3 * torch.randn(weight.shape, generator=gen))
    return model


def rotation_matrix(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s], [s, c]])


@pytest.mark.parametrize("offset_scale", ["step", "deviation"])
def test_agent_frame_predictions_rotate_and_translate_with_the_scene(offset_scale):
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, offset_scale=offset_scale))
    positions, valid = curved_scene()
    model.fit_normalisation(positions, valid, num_observed=4)
    trained_looking(model)
    rot, shift = rotation_matrix(0.7), torch.tensor([12.0, -5.0])
    moved = positions @ rot.T + shift
    base = model.predict(positions, valid, 4).rollout
    other = model.predict(moved, valid, 4).rollout
    torch.testing.assert_close(other.mean, base.mean @ rot.T + shift, atol=2e-3, rtol=1e-4)
    cov_base, cov_other = base.covariance(), other.covariance()
    torch.testing.assert_close(cov_other, rot @ cov_base @ rot.T, atol=1e-6, rtol=1e-3)
    assert (base.mean - (2 * positions[:, 3] - positions[:, 2]).unsqueeze(1)).abs().max() > 1e-3


def test_scene_frame_model_is_not_rotation_equivariant():
    """The contrast that makes the test above meaningful: the paper's inputs are world axes."""
    torch.manual_seed(0)
    model = trained_looking(SmoothAttentionPredictor(ModelConfig(**SMALL)))
    positions, valid = curved_scene()
    rot = rotation_matrix(0.7)
    base = model.predict(positions, valid, 4).rollout.mean
    other = model.predict(positions @ rot.T, valid, 4).rollout.mean
    assert (other - base @ rot.T).abs().max() > 1e-2


def test_untrained_agent_model_predicts_constant_velocity():
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, offset_scale="deviation"))
    positions, valid = curved_scene()
    model.fit_normalisation(positions, valid, 4)
    out = model.predict(positions, valid, 4).rollout.mean  # (B, T_pred, N, 2)
    velocity = positions[:, 3] - positions[:, 2]
    steps = torch.arange(1, positions.shape[1] - 3, dtype=torch.float32).view(1, -1, 1, 1)
    expected = positions[:, 3].unsqueeze(1) + steps * velocity.unsqueeze(1)
    torch.testing.assert_close(out, expected, atol=1e-4, rtol=1e-5)


def test_agent_frames_follow_the_last_observed_displacement():
    positions, valid = curved_scene()
    origin, rotation = agent_frames(positions, valid, num_observed=4)
    step = positions[:, 3] - positions[:, 2]
    torch.testing.assert_close(origin, positions[:, 3])
    torch.testing.assert_close(rotation, step / step.norm(dim=-1, keepdim=True))


def test_fit_normalisation_offset_scale_is_the_rms_second_difference_in_agent_frames():
    positions, valid = curved_scene(steps=8)
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, offset_scale="deviation"))
    model.fit_normalisation(positions, valid, num_observed=4)
    p = positions.numpy().astype(np.float64)
    heading = p[:, 3] - p[:, 2]  # (B, N, 2)
    unit = heading / np.linalg.norm(heading, axis=-1, keepdims=True)
    dev = p[:, 2:] - 2 * p[:, 1:-1] + p[:, :-2]  # (B, T-2, N, 2)
    along = (dev * unit[:, None]).sum(-1)
    across = (dev * np.stack([-unit[..., 1], unit[..., 0]], -1)[:, None]).sum(-1)
    expected = np.sqrt([np.mean(along**2), np.mean(across**2)])
    np.testing.assert_allclose(model.head.offset_std.numpy(), expected, rtol=1e-4)


def test_fit_normalisation_anchor_scale_is_the_rms_velocity_change_since_the_last_observation():
    positions, valid = curved_scene(steps=9)
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, rollout_prior="anchored"))
    model.fit_normalisation(positions, valid, num_observed=4)
    p = positions.numpy().astype(np.float64)
    heading = p[:, 3] - p[:, 2]  # (B, N, 2) the last observed velocity
    unit = heading / np.linalg.norm(heading, axis=-1, keepdims=True)
    change = (p[:, 4:] - p[:, 3:-1]) - heading[:, None]  # (B, T_pred, N, 2)
    along = (change * unit[:, None]).sum(-1)
    across = (change * np.stack([-unit[..., 1], unit[..., 0]], -1)[:, None]).sum(-1)
    expected = np.sqrt([np.mean(along**2), np.mean(across**2)])
    np.testing.assert_allclose(model.head.anchor_std.numpy(), expected, rtol=1e-4)


def test_anchored_rollout_is_constant_velocity_at_init_and_a_bias_drifts_linearly():
    """rollout_prior="anchored": a constant F_roll output c moves the k-th predicted step by
    k * c (scaled, in the agent frame) off constant velocity, from the first predicted step on:
    linear, where the one-step prior integrates the same bias twice."""
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(ModelConfig(**SMALL, **AGENT, rollout_prior="anchored"))
    positions, valid = curved_scene(steps=12)
    model.fit_normalisation(positions, valid, 4)
    velocity = positions[:, 3] - positions[:, 2]  # (B, N, 2)
    j = torch.arange(positions.shape[1] - 4, dtype=torch.float32).view(1, -1, 1, 1)
    constant_velocity = positions[:, 3].unsqueeze(1) + (j + 1) * velocity.unsqueeze(1)
    out = model.predict(positions, valid, 4).rollout.mean  # (B, T_pred, N, 2)
    torch.testing.assert_close(out, constant_velocity, atol=1e-4, rtol=1e-5)
    bias = torch.tensor([0.5, -2.0])
    with torch.no_grad():
        model.head.f_roll.bias.copy_(bias)
    out = model.predict(positions, valid, 4).rollout.mean
    unit = velocity / velocity.norm(dim=-1, keepdim=True)  # agent frame axes
    normal = torch.stack([-unit[..., 1], unit[..., 0]], -1)
    local = bias * model.head.anchor_std  # (2,)
    per_step = local[0] * unit + local[1] * normal  # (B, N, 2) world axes
    torch.testing.assert_close(
        out, constant_velocity + (j + 1) * per_step.unsqueeze(1), atol=1e-4, rtol=1e-5
    )


def test_rotate_tril_gives_the_rotated_covariance():
    gen = torch.Generator().manual_seed(3)
    tril = torch.rand(5, 3, generator=gen) + torch.tensor([0.1, -0.5, 0.1])
    angle = torch.rand(5, generator=gen) * 6.0
    rotation = torch.stack([angle.cos(), angle.sin()], -1)
    zero = torch.zeros(5, 2)
    got = Gaussian2D(zero, rotate_tril(tril, rotation)).covariance()
    rot = torch.stack([torch.stack([angle.cos(), -angle.sin()], -1), rotation], -2)
    rot = torch.stack([rot[:, 0], torch.stack([angle.sin(), angle.cos()], -1)], -2)
    expected = rot @ Gaussian2D(zero, tril).covariance() @ rot.transpose(-1, -2)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-4)
    back = rotate(rotate(torch.ones(5, 2), rotation), rotation, inverse=True)
    torch.testing.assert_close(back, torch.ones(5, 2))


def test_agent_only_options_need_the_agent_frame():
    options = (
        {"standardise": True},
        {"edge_velocity": True},
        {"offset_scale": "deviation"},
        {"rollout_prior": "anchored"},
    )
    for option in options:
        with pytest.raises(ValueError, match="needs frame='agent'"):
            ModelConfig(**option)


def test_presets_paper_is_the_dataclass_defaults_and_agent_differs():
    model, train = make_configs("ours", preset="paper")
    assert model == ModelConfig() and train == TrainConfig()
    model, train = make_configs("ours", preset="agent")
    assert model.frame == "agent" and train.mean_loss == "displacement"
    assert set(PRESETS) >= {"paper", "agent", "crowd"}
    crowd_model, crowd_train = make_configs("ours", preset="crowd")  # agent, for pedestrians
    assert (crowd_model.neighbours, crowd_model.neighbour_k) == ("knn", 8)
    assert crowd_model.highway_steps == model.highway_steps and not crowd_model.highway_attended
    assert (crowd_train.batch_size, crowd_train.epochs) == (16, 20)
    with pytest.raises(ValueError, match="unknown preset"):
        make_configs("ours", preset="nope")


def test_cosine_learning_rate_runs_from_lr_to_the_final_ratio():
    config = TrainConfig(lr=2e-3, lr_schedule="cosine", lr_final_ratio=0.1)
    rates = [learning_rate(config, step, 11) for step in range(11)]
    assert rates[0] == pytest.approx(2e-3) and rates[-1] == pytest.approx(2e-4)
    assert rates[5] == pytest.approx(1.1e-3)  # halfway: the mean of the two ends
    assert all(a > b for a, b in zip(rates, rates[1:], strict=False))
    assert learning_rate(TrainConfig(lr=2e-3), 7, 11) == 2e-3


def _output(mean: torch.Tensor, rollout_mean: torch.Tensor) -> ModelOutput:
    """A ModelOutput with unit stds: (B, T-1, N, 2) one-step and (B, T_pred, N, 2) rollout."""

    def unit(m: torch.Tensor) -> Gaussian2D:
        return Gaussian2D(m, torch.tensor([1.0, 0.0, 1.0]).expand(*m.shape[:-1], 3).clone())

    b, s1, n, _ = mean.shape
    t_pred = rollout_mean.shape[1]
    return ModelOutput(
        one_step=unit(mean),
        attention=torch.full((b, s1, n, n - 1), 1.0 / (n - 1)),
        rollout=unit(rollout_mean),
        rollout_attention=torch.full((b, t_pred, n, n - 1), 1.0 / (n - 1)),
        rollout_present=torch.ones(b, n, dtype=torch.bool),
    )


def test_displacement_mean_loss_hand_values_and_first_step_mask():
    positions = torch.zeros(1, 4, 2, 2)  # T = 4, N = 2, everything at the origin
    valid = torch.ones(1, 4, 2, dtype=torch.bool)
    mean = torch.zeros(1, 3, 2, 2, requires_grad=True)  # predictions of t = 1, 2, 3
    with torch.no_grad():
        mean[0, 0, :, 0] = 2.0  # the first step misses by 2 m (no velocity known)
        mean[0, 1, 0] = torch.tensor([3.0, 4.0])  # 5 m
    rollout = torch.zeros(1, 2, 2, 2, requires_grad=True)  # t = 2, 3
    with torch.no_grad():
        rollout[0, 1, 1] = torch.tensor([0.6, 0.8])  # 1 m
    weights = LossWeights(beta1=0, beta2=0, mean_loss="displacement", needs_previous=True)
    loss, terms = compute_loss(_output(mean, rollout), positions, valid, 2, weights)
    assert terms["de"] == pytest.approx(5.0 / 4)  # steps t = 2, 3 of both agents
    assert terms["de_seq"] == pytest.approx(1.0 / 4)
    loss.backward()
    assert torch.all(mean.grad[0, 0] == 0)  # the first step is left out
    torch.testing.assert_close(mean.grad[0, 1, 0], torch.tensor([0.6, 0.8]) / 4)
    # the NLL sees detached means: the gradient is the displacement term's alone
    assert torch.all(mean.grad[0, 2] == 0)
    weights = LossWeights(beta1=0, beta2=0, needs_previous=False)
    _, terms = compute_loss(_output(mean, rollout), positions, valid, 2, weights)
    assert "de" not in terms


def test_fit_normalisation_works_for_every_attention_mode():
    positions, valid = curved_scene()
    for mode in ("learned", "uniform", "oracle"):
        model = SmoothAttentionPredictor(
            ModelConfig(**SMALL, **AGENT, offset_scale="deviation", attention_mode=mode)
        )
        model.fit_normalisation(positions, valid, 4)
        assert torch.all(model.head.offset_std > 0)


def test_agent_preset_run_keeps_its_fitted_scales_and_is_deterministic(dataset_file, tmp_path):
    """The training split's statistics travel in the checkpoint; a second run with the same
    seed gives the same weights and the same evaluation."""
    from predictor.checkpoints import load_model
    from predictor.evaluation import evaluate_run
    from predictor.training import train
    from trajectory_data.torch_dataset import TrajectoryDataset

    model_cfg, train_cfg = make_configs("ours", SMALL, preset="agent", epochs=2)
    runs = [tmp_path / "a", tmp_path / "b"]
    for run in runs:
        train(dataset_file, model_cfg, train_cfg, run, progress=False)
    model, _ = load_model(runs[0] / "best.pt")
    train_set = TrajectoryDataset(dataset_file, "train")
    fresh = SmoothAttentionPredictor(resolve_roles(model_cfg, train_set.meta.role_names))
    scenes = train_set.all()
    fresh.fit_normalisation(
        scenes.positions, scenes.valid, train_set.meta.num_observed, scenes.roles
    )
    # the preset refits the highway's maps at every epoch start (tested in test_highway); the
    # statistics below are fitted once, before training
    assert model_cfg.attended_refit
    names = ("input_mean", "input_std", "offset_std", "anchor_std")
    state, fresh_state = model.state_dict(), fresh.state_dict()  # named as in checkpoints
    for name in names + ("attended_mean", "attended_std"):
        torch.testing.assert_close(state[name], fresh_state[name])
    assert not torch.equal(state["input_std"], torch.ones_like(state["input_std"]))
    first, second = (evaluate_run(run, dataset_file).to_dict() for run in runs)
    first.pop("run"), second.pop("run")
    assert first == second
    assert first["diagnostics"]["one_step"]["all_agents"]["model_m"] is not None


def test_training_skips_the_highway_fit_that_the_first_refit_replaces(
    dataset_file, tmp_path, monkeypatch
):
    """With attended_refit, training leaves the highway's maps to the first epoch's refit
    (fit_maps=False): the run is the same, bit for bit, as one that fits them first."""
    from predictor.training import train

    model_cfg, train_cfg = make_configs("ours", SMALL, preset="agent", epochs=2)
    train(dataset_file, model_cfg, train_cfg, tmp_path / "skipped", progress=False)
    fit_normalisation = SmoothAttentionPredictor.fit_normalisation
    calls = []

    def fit_every_map(self, *args, fit_maps: bool = True):
        calls.append(fit_maps)
        fit_normalisation(self, *args, fit_maps=True)

    monkeypatch.setattr(SmoothAttentionPredictor, "fit_normalisation", fit_every_map)
    train(dataset_file, model_cfg, train_cfg, tmp_path / "fitted", progress=False)
    assert calls == [False]  # training asked to skip the maps; this run fitted them anyway
    for name in ("best.pt", "last.pt"):
        skipped, fitted = (
            torch.load(tmp_path / run / name, weights_only=True)["model_state"]
            for run in ("skipped", "fitted")
        )
        assert skipped.keys() == fitted.keys()
        for key in skipped:
            assert torch.equal(skipped[key], fitted[key]), key


def test_variants_without_a_rollout_loss_roll_out_their_one_step_model():
    """F_roll is trained by the rollout loss alone: S-Attn under the agent preset uses the
    one-step prior, and asking for the anchored one explicitly is an error."""
    model, _ = make_configs("s_attn", preset="agent")
    assert model.rollout_prior == "previous"
    assert make_configs("ours", preset="agent")[0].rollout_prior == "anchored"
    with pytest.raises(ValueError, match="no rollout loss"):
        make_configs("s_attn", {"rollout_prior": "anchored"}, preset="agent")


@pytest.mark.parametrize("inverse", [False, True])
def test_rotate_is_the_rotation_matrix_product_broadcast_over_leading_steps(inverse: bool):
    # vectors (S, B, N, 2) by per-agent rotations (B, N, 2): R v, or R^T v with inverse
    gen = torch.Generator().manual_seed(4)
    vectors = torch.randn(3, 2, 5, 2, generator=gen, dtype=torch.float64)
    angle = torch.rand(2, 5, generator=gen, dtype=torch.float64) * 6.0
    rotation = torch.stack([angle.cos(), angle.sin()], -1)
    sign = -1.0 if inverse else 1.0
    matrix = torch.stack(
        [
            torch.stack([angle.cos(), -sign * angle.sin()], -1),
            torch.stack([sign * angle.sin(), angle.cos()], -1),
        ],
        -2,
    )  # (B, N, 2, 2)
    expected = (matrix @ vectors.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(rotate(vectors, rotation, inverse), expected, rtol=0, atol=1e-12)
