"""The linear autoregressive highway (ModelConfig.highway_steps): its closed-form fit, and the
untrained model's rollout with it against closed-form kinematics."""

from __future__ import annotations

import math

import pytest
import torch
from torch import Tensor

from predictor.agent_frame import agent_frames
from predictor.config import HIGHWAY_SWITCHES, ModelConfig
from predictor.highway import (
    CROSS_FIT_FOLDS,
    attended_changes,
    constant_velocity_transform,
    fold_of,
    future_offsets,
    history_features,
    neighbour_features,
    velocity_changes,
)
from predictor.highway_fit import (
    HIGHWAY_ALPHAS,
    change_bounds,
    fit_cross_fitted,
    fit_highway,
    fit_highway_subsets,
)
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import edge_index
from predictor.presets import PRESETS, make_configs

torch.set_num_threads(1)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
ANCHORED = {
    "frame": "agent",
    "standardise": True,
    "edge_velocity": True,
    "offset_scale": "deviation",
    "rollout_prior": "anchored",
}


def accelerating_scenes(batch: int, steps: int, agents: int, seed: int = 0):
    """Agents under a constant, random acceleration vector (world axes): p_t = p_0 + v_0 t +
    a t^2 / 2 [m, per step]. In each agent's frame the future offset from constant velocity
    after k steps is a_local k (k + 1) / 2 with a_local = v^{T_obs-1} - v^{T_obs-2}: a linear
    function of the observed velocities."""
    gen = torch.Generator().manual_seed(seed)
    start = 50.0 * torch.rand(batch, 1, agents, 2, generator=gen, dtype=torch.float64)
    angle = 2 * math.pi * torch.rand(batch, 1, agents, 1, generator=gen, dtype=torch.float64)
    speed = 2.0 + torch.rand(batch, 1, agents, 1, generator=gen, dtype=torch.float64)
    velocity = speed * torch.cat([angle.cos(), angle.sin()], -1)
    accel = 0.02 * torch.randn(batch, 1, agents, 2, generator=gen, dtype=torch.float64)
    t = torch.arange(steps, dtype=torch.float64).view(1, -1, 1, 1)
    positions = start + velocity * t + accel * t * t / 2
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    return positions.float(), valid


def test_fit_recovers_an_exact_linear_map_as_per_step_velocity_changes():
    gen = torch.Generator().manual_seed(0)
    scenes, agents, num_features, num_pred = 60, 3, 6, 5
    features = torch.randn(scenes, agents, num_features, generator=gen, dtype=torch.float64)
    true_w = torch.randn(num_features, num_pred, 2, generator=gen, dtype=torch.float64)
    true_b = torch.randn(num_pred, 2, generator=gen, dtype=torch.float64)
    offsets = torch.einsum("bnf,fkc->bnkc", features, true_w) + true_b  # (B, N, T_pred, 2)
    usable = torch.ones(scenes, agents, dtype=torch.bool)
    roles = torch.zeros(scenes, agents, dtype=torch.long)
    weight, bias, alphas = fit_highway(features.float(), offsets.float(), usable, roles, 1, 7)
    assert weight.shape == (1, num_features, 7, 2) and bias.shape == (1, 7, 2)
    assert alphas[0] == pytest.approx(1e-3)  # noise-free: the smallest alpha of the grid
    change = velocity_changes(features.float(), usable, weight[roles], bias[roles])  # (B,N,7,2)
    torch.testing.assert_close(
        change[:, :, :num_pred].cumsum(2), offsets.float(), atol=2e-3, rtol=0
    )
    # beyond the data's horizon the last velocity change repeats
    torch.testing.assert_close(
        change[:, :, num_pred:], change[:, :, num_pred - 1 :][:, :, :1].expand(-1, -1, 2, -1)
    )


@pytest.mark.parametrize("with_moments", [False, True])
def test_cross_fitted_maps_equal_fits_on_each_folds_scenes_alone(with_moments):
    # the per-scene sums are computed once for the six fits; each must be bit-identical to
    # fitting the scenes it keeps on their own (sliced tensors, groups renumbered), alphas
    # included. Noisy targets put the alphas inside the grid, where the folds decide them.
    gen = torch.Generator().manual_seed(3)
    scenes, agents, num_features, num_pred = 23, 4, 5, 3
    features = torch.randn(scenes, agents, num_features, generator=gen, dtype=torch.float64)
    mix = 0.3 * torch.randn(num_features, num_pred, 2, generator=gen, dtype=torch.float64)
    noise = 2.0 * torch.randn(scenes, agents, num_pred, 2, generator=gen, dtype=torch.float64)
    offsets = (torch.einsum("bnf,fkc->bnkc", features, mix) + noise).float()
    usable = torch.rand(scenes, agents, generator=gen) > 0.2
    roles = torch.randint(0, 2, (scenes, agents), generator=gen)
    moments = weights = None
    if with_moments:  # rows around each sample's mean: E[x x^T] = x x^T + a PSD spread
        spread = torch.randn(scenes, agents, num_features, 2, generator=gen, dtype=torch.float64)
        outer = features.unsqueeze(-1) * features.unsqueeze(-2)
        moments = (outer + spread @ spread.transpose(-1, -2)).float()
        weights = 0.1 + torch.rand(scenes, agents, generator=gen, dtype=torch.float64).float()
    features = features.float()
    fold = fold_of(torch.arange(scenes), CROSS_FIT_FOLDS)
    subsets = [torch.ones(scenes, dtype=torch.bool)] + [fold != k for k in range(5)]
    together = fit_highway_subsets(
        features, offsets, usable, roles, 2, 4, subsets, moments, weights
    )
    inside = 0
    for keep, (weight, bias, alphas) in zip(subsets, together, strict=True):
        alone = fit_highway(
            features[keep],
            offsets[keep],
            usable[keep],
            roles[keep],
            2,
            4,
            None if moments is None else moments[keep],
            None if weights is None else weights[keep],
        )
        assert alphas == alone[2] and set(alphas) == {0, 1}
        assert torch.equal(weight, alone[0]) and torch.equal(bias, alone[1])
        inside += sum(min(HIGHWAY_ALPHAS) < a < max(HIGHWAY_ALPHAS) for a in alphas.values())
    assert inside >= 6  # the check can see a wrong fold assignment
    # fit_cross_fitted returns these six fits
    cross = fit_cross_fitted(features, offsets, usable, roles, 2, 4, moments, weights)
    assert torch.equal(cross[0], together[0][0]) and torch.equal(cross[1], together[0][1])
    assert torch.equal(cross[2], torch.stack([w for w, _, _ in together[1:]]))
    assert torch.equal(cross[3], torch.stack([b for _, b, _ in together[1:]]))


def test_a_role_with_one_training_scene_keeps_constant_velocity():
    features = torch.randn(4, 2, 4)
    offsets = torch.randn(4, 2, 3, 2)
    roles = torch.tensor([[0, 1], [0, 0], [0, 0], [0, 0]])
    weight, bias, alphas = fit_highway(
        features, offsets, torch.ones(4, 2, dtype=torch.bool), roles, 2, 3
    )
    assert set(alphas) == {0}
    assert not weight[1].any() and not bias[1].any()


def test_change_bounds_are_each_maps_target_range_with_zero_included():
    # two agents of map 0 (one not a sample) and one of map 1; offsets over 3 predicted steps
    offsets = torch.tensor(
        [
            [[1.0, 0.5], [3.0, 0.0], [4.0, -1.0]],  # changes (1, .5) (2, -.5) (1, -1)
            [[-2.0, 1.0], [-3.0, 2.0], [-3.0, 3.0]],  # changes (-2, 1) (-1, 1) (0, 1)
            [[9.0, 9.0], [0.0, 0.0], [9.0, 9.0]],  # not a sample
            [[0.5, 0.5], [1.0, 1.0], [1.5, 1.5]],  # map 1: changes (.5, .5) each step
        ]
    ).unsqueeze(0)  # (B=1, N=4, T_pred=3, 2)
    samples = torch.tensor([[True, True, False, True]])
    maps = torch.tensor([[0, 0, 0, 1]])
    low, high = change_bounds(offsets, samples, maps, num_maps=3, horizon=4)
    assert low.shape == high.shape == (3, 4, 2)
    expected_low = [[-2.0, 0.0], [-1.0, -0.5], [0.0, -1.0], [0.0, -1.0]]  # step 4 repeats 3
    expected_high = [[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [1.0, 1.0]]
    assert low[0].tolist() == expected_low and high[0].tolist() == expected_high
    assert low[1].tolist() == [[0.0, 0.0]] * 4 and high[1].tolist() == [[0.5, 0.5]] * 4
    assert not low[2].any() and not high[2].any()  # no samples: constant velocity only


def test_the_highway_never_leaves_its_fitted_range_and_old_checkpoints_stay_unbounded():
    num_observed, steps = 8, 20
    train, valid = accelerating_scenes(batch=40, steps=steps, agents=3, seed=1)
    config = ModelConfig(**SMALL, **ANCHORED, highway_steps=4, highway_horizon=12)
    model = SmoothAttentionPredictor(config)
    model.fit_normalisation(train, valid, num_observed)
    # 100 times the training accelerations: far outside the range the map was fitted on
    start, _ = accelerating_scenes(batch=5, steps=steps, agents=3, seed=2)
    t = torch.arange(steps, dtype=torch.float32).view(1, -1, 1, 1)
    extreme = start + 99.0 * (start[:, 2:3] - 2 * start[:, 1:2] + start[:, :1]) * t * t / 2
    test_valid = torch.ones(5, steps, 3, dtype=torch.bool)
    rollout = model.predict(extreme, test_valid, num_observed).rollout.mean  # (B, T_pred, N, 2)
    # the untrained network adds nothing: each step's velocity change since T_obs-1 is the
    # highway's, whose size the fitted range bounds (the frame's rotation keeps lengths)
    path = torch.cat([extreme[:, num_observed - 2 : num_observed], rollout], 1)
    velocity = path[:, 1:] - path[:, :-1]  # (B, T_pred + 1, N, 2)
    change = (velocity[:, 1:] - velocity[:, :1]).norm(dim=-1)  # (B, T_pred, N)
    highway = model.highway
    largest = torch.maximum(-highway.highway_low, highway.highway_high)[0].norm(dim=-1)  # (12,)
    limit = torch.cat([largest, largest[-1:].expand(steps - num_observed - 12)])
    assert (change <= limit.view(1, -1, 1) + 1e-4).all()
    assert largest.max() < 1.0  # [m/step]: the training scenes' changes are small
    # a checkpoint without the range (written before it existed) loads unbounded
    state = {
        k: v for k, v in model.state_dict().items() if k not in ("highway_low", "highway_high")
    }
    old = SmoothAttentionPredictor(config)
    old.load_state_dict(old.fill_unclamped_range(state))
    assert old.highway.highway_high.isinf().all()
    assert (old.highway.highway_low == -math.inf).all()
    unbounded = old.predict(extreme, test_valid, num_observed).rollout.mean
    path = torch.cat([extreme[:, num_observed - 2 : num_observed], unbounded], 1)
    velocity = path[:, 1:] - path[:, :-1]
    assert (velocity[:, 1:] - velocity[:, :1]).norm(dim=-1).max() > 10 * largest.max()


def test_history_and_future_features_follow_the_kinematics():
    positions, valid = accelerating_scenes(batch=2, steps=10, agents=3)
    pos, present = positions.transpose(0, 1), valid.transpose(0, 1)
    rotation = torch.tensor([1.0, 0.0]).expand(2, 3, 2)  # world axes
    features, usable = history_features(pos, present, 6, rotation, 3)
    assert usable.all()
    # 3 velocities (the last without its lateral component: zero in the agent's own frame)
    # and 2 accelerations
    assert features.shape == (2, 3, 3 * 2 - 1 + 2 * 2)
    torch.testing.assert_close(features[..., 4], positions[:, 5, :, 0] - positions[:, 4, :, 0])
    torch.testing.assert_close(features[..., :2], positions[:, 3] - positions[:, 2])
    accel = positions[:, 5] - 2 * positions[:, 4] + positions[:, 3]  # (B, N, 2)
    torch.testing.assert_close(features[..., -2:], accel, atol=1e-5, rtol=1e-4)
    offsets, complete = future_offsets(pos, present, 6, rotation)
    accel = accel.unsqueeze(2)  # (B, N, 1, 2)
    k = torch.arange(1, 5, dtype=torch.float32).view(1, 1, -1, 1)
    torch.testing.assert_close(offsets, accel * k * (k + 1) / 2, atol=1e-4, rtol=1e-3)
    valid[0, 2, 1] = False  # agent 1 of scene 0 misses a history step
    _, usable = history_features(pos, valid.transpose(0, 1), 6, rotation, 3)
    assert usable.tolist() == [[True, False, True], [True, True, True]]


def test_untrained_model_with_a_fitted_highway_rolls_out_the_true_accelerating_motion():
    num_observed, steps = 8, 20
    train, valid = accelerating_scenes(batch=40, steps=steps, agents=3, seed=1)
    test, test_valid = accelerating_scenes(batch=5, steps=steps, agents=3, seed=2)
    config = ModelConfig(**SMALL, **ANCHORED, highway_steps=4, highway_horizon=12)
    model = SmoothAttentionPredictor(config)
    truth = test[:, num_observed:]  # (B, T_pred, N, 2)
    before = model.predict(test, test_valid, num_observed).rollout.mean  # unfitted: zero map
    model.fit_normalisation(train, valid, num_observed)
    after = model.predict(test, test_valid, num_observed).rollout.mean
    # unfitted (and before any training) the rollout is constant velocity from T_obs-1
    velocity = (test[:, num_observed - 1] - test[:, num_observed - 2]).unsqueeze(1)
    k = torch.arange(1, steps - num_observed + 1, dtype=torch.float32).view(1, -1, 1, 1)
    torch.testing.assert_close(before, test[:, num_observed - 1 : num_observed] + k * velocity)
    error = (after - truth).norm(dim=-1)
    assert error.max() < 0.01 * (before - truth).norm(dim=-1).max()
    assert error[:, :12].max() < 1e-2  # within the fitted horizon: the kinematics [m]
    # the highway travels with the checkpoint
    clone = SmoothAttentionPredictor(config)
    clone.load_state_dict(model.state_dict())
    torch.testing.assert_close(clone.predict(test, test_valid, num_observed).rollout.mean, after)


def test_highway_needs_the_anchored_rollout_and_s_attn_drops_it():
    with pytest.raises(ValueError, match="anchored"):
        ModelConfig(frame="agent", highway_steps=4)
    model, _ = make_configs("s_attn", {"highway_steps": 12}, preset="agent")
    assert model.highway_steps == 0 and model.rollout_prior == "previous"
    for preset in PRESETS:  # every highway switch back at its default, whatever the preset
        model, _ = make_configs("s_attn", preset=preset)
        for name in HIGHWAY_SWITCHES:
            assert getattr(model, name) == getattr(ModelConfig(), name), (preset, name)


def test_training_scenes_roll_out_with_the_map_fitted_without_their_fold():
    num_observed, steps = 8, 14
    train, valid = accelerating_scenes(batch=30, steps=steps, agents=2, seed=3)
    train = train + 0.002 * torch.randn(train.shape, generator=torch.Generator().manual_seed(4))
    config = ModelConfig(**SMALL, **ANCHORED, highway_steps=4, highway_horizon=6)
    model = SmoothAttentionPredictor(config)
    model.fit_normalisation(train, valid, num_observed)
    scenes = torch.arange(30)
    held_out = scenes % CROSS_FIT_FOLDS == 2  # the scenes of fold 2
    reference = SmoothAttentionPredictor(config)  # fitted on the other folds only
    reference.fit_normalisation(train[~held_out], valid[~held_out], num_observed)
    out = model(train, valid, num_observed, sample=False, scenes=scenes).rollout.mean
    expected = reference.predict(train[held_out], valid[held_out], num_observed).rollout.mean
    torch.testing.assert_close(out[held_out], expected)
    full = model.predict(train, valid, num_observed).rollout.mean  # the map of all scenes
    assert (full[held_out] - expected).abs().max() > 1e-4


def test_fewer_observed_steps_than_the_highway_reads_leave_the_oldest_features_zero():
    positions, valid = accelerating_scenes(batch=2, steps=10, agents=3)
    pos, present = positions.transpose(0, 1), valid.transpose(0, 1)
    rotation = torch.tensor([1.0, 0.0]).expand(2, 3, 2)
    short, _ = history_features(pos, present, 4, rotation, 3)  # 3 velocities, as asked
    padded, usable = history_features(pos, present, 4, rotation, 5)  # 5 asked, 3 observed
    assert usable.all() and padded.shape[-1] == 4 * 5 - 3
    assert not padded[..., :4].any() and not padded[..., 9:13].any()  # 2 velocities, 2 accels
    torch.testing.assert_close(padded[..., 4:9], short[..., :5])
    torch.testing.assert_close(padded[..., 13:], short[..., 5:])
    features, usable = history_features(pos, present, 2, rotation, 3)  # one velocity only
    assert features.shape == (2, 3, 9) and not features.any() and not usable.any()


def test_neighbour_features_are_the_other_agents_motion_in_the_agents_frame():
    # agent 0 drives north at 1 m/step, agent 1 east at 1 m/step from (3, 5); agent 2 misses
    # step 2 of the window, so it has no edges
    t = torch.arange(5, dtype=torch.float32).view(1, -1, 1)
    north = torch.cat([0 * t, t], -1)  # (1, T, 2)
    east = torch.cat([3 + t, 5 + 0 * t], -1)
    positions = torch.stack([north, east, east + 10], 2)  # (1, T, 3, 2)
    valid = torch.ones(1, 5, 3, dtype=torch.bool)
    valid[0, 2, 2] = False
    _, rotation = agent_frames(positions, valid, 4)  # agent 0's x axis points north
    _, head = edge_index(3)
    pos, present = positions.transpose(0, 1), valid.transpose(0, 1)
    features, mask = neighbour_features(pos, present, 4, rotation, 2, head)
    assert features.shape == (1, 3, 2, 6)
    # edge 0 -> 1 at step 3: agent 1 is at (6, 5), agent 0 at (0, 3): 2 m ahead of it and
    # 6 m to its right; agent 1's velocity (1, 0) is (0, -1) in agent 0's frame
    expected = torch.tensor([2.0, -6.0, 0.0, -1.0, 0.0, -1.0])
    torch.testing.assert_close(features[0, 0, 0], expected)
    assert mask[0].tolist() == [[True, False], [True, False], [False, False]]
    assert not features[0, 0, 1].any() and not features[0, 2].any()


def test_attended_changes_with_one_hot_attention_read_the_attended_agent_alone():
    gen = torch.Generator().manual_seed(0)
    features = torch.randn(2, 3, 2, 4, generator=gen)  # (B, N, N-1, F)
    mask = torch.ones(2, 3, 2, dtype=torch.bool)
    mask[1, 2, 0] = False  # an edge off the graph contributes nothing
    mean, std = torch.randn(4, generator=gen), torch.rand(4, generator=gen) + 0.5
    weight = torch.randn(2, 3, 4, 5, 2, generator=gen)  # (B, N, F, horizon, 2)
    theta = torch.zeros(2, 3, 2)
    theta[..., 1] = 1.0  # everyone attends its second other agent
    out = attended_changes(features, mask, theta, mean, std, weight)
    standard = (features[:, :, 1] - mean) / std  # (B, N, F)
    torch.testing.assert_close(out, torch.einsum("bnf,bnfkc->bnkc", standard, weight))
    theta = torch.zeros(2, 3, 2)
    theta[1, 2, 0] = 1.0
    assert not attended_changes(features, mask, theta, mean, std, weight)[1, 2].any()


def test_attended_highway_starts_as_the_plain_highway_and_reads_the_attention():
    num_observed, steps = 8, 14
    train, valid = accelerating_scenes(batch=20, steps=steps, agents=3, seed=5)
    plain = ModelConfig(**SMALL, **ANCHORED, highway_steps=4, highway_horizon=6)
    attended = ModelConfig(**{**plain.__dict__, "highway_attended": True})
    models = []
    for config in (plain, attended):
        torch.manual_seed(0)
        models.append(SmoothAttentionPredictor(config))
        models[-1].fit_normalisation(train, valid, num_observed)
    outputs = [m.predict(train, valid, num_observed).rollout.mean for m in models]
    torch.testing.assert_close(outputs[1], outputs[0])  # zero map: no change
    model = models[1]
    highway = model.highway
    weight = torch.randn(highway.attended_weight.shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():  # a random map leaves the fitted range; the range is tested apart
        highway.highway_low.fill_(-math.inf)
        highway.highway_high.fill_(math.inf)

    def first_step_shift() -> torch.Tensor:
        """What the map moves the first predicted position by (the network's part cancels)."""
        with torch.no_grad():
            highway.attended_weight.copy_(weight)
            moved = model.predict(train, valid, num_observed)
            highway.attended_weight.zero_()
            still = model.predict(train, valid, num_observed).rollout.mean
        return (moved.rollout.mean - still)[:, 0], moved.attention[:, -1]

    shift, theta = first_step_shift()  # theta: the attention at the last observed step
    _, head = edge_index(3)
    _, rotation = agent_frames(train, valid, num_observed)
    pos, present = train.transpose(0, 1), valid.transpose(0, 1)
    features, mask = neighbour_features(pos, present, num_observed, rotation, 4, head)
    change = (
        attended_changes(
            features,
            mask,
            theta,
            highway.attended_mean,
            highway.attended_std,
            weight[0].expand(20, 3, -1, -1, -1),
        )[:, :, 0]
        * model.head.anchor_std
    )  # agent frame
    world = torch.stack(
        [
            rotation[..., 0] * change[..., 0] - rotation[..., 1] * change[..., 1],
            rotation[..., 1] * change[..., 0] + rotation[..., 0] * change[..., 1],
        ],
        -1,
    )
    torch.testing.assert_close(shift, world, atol=1e-5, rtol=1e-4)
    with torch.no_grad():  # another attention, another shift
        model.attention.f_attn.weight.mul_(3.0)
    other, other_theta = first_step_shift()
    assert (other_theta - theta).abs().max() > 1e-3
    assert (other - shift).abs().max() > 1e-4
    loss = model(train, valid, num_observed, sample=False).rollout.mean.square().sum()
    loss.backward()
    assert highway.attended_weight.grad.abs().sum() > 0  # trained by the rollout's loss


def test_attended_highway_needs_the_highway_and_s_attn_drops_it():
    with pytest.raises(ValueError, match="highway_attended needs highway_steps"):
        ModelConfig(**ANCHORED, highway_attended=True)
    model, _ = make_configs("s_attn", {"highway_attended": True}, preset="agent")
    assert not model.highway_attended and model.highway_steps == 0


def constant_and_turning_histories(observed: int) -> tuple[Tensor, Tensor, Tensor]:
    """Positions (T, B=1, N=2, 2), float64: agent 0 at constant velocity (3, 1) m/step, agent 1
    turning; all present; each agent's frame rotation (B, N, 2)."""
    t = torch.arange(observed, dtype=torch.float64)
    straight = torch.stack([3.0 * t, 1.0 * t], -1)
    turning = torch.stack([2.0 * t, 0.05 * t**2], -1)
    pos = torch.stack([straight, turning], 1).unsqueeze(1)  # (T, 1, 2, 2)
    present = torch.ones(observed, 1, 2, dtype=torch.bool)
    heading = pos[-1] - pos[-2]  # (1, 2, 2)
    return pos, present, heading / heading.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("observed", [9, 5])  # the whole window, and a short history
def test_constant_velocity_transform_maps_a_constant_history_to_zero(observed: int):
    pos, present, rotation = constant_and_turning_histories(observed)
    features, usable = history_features(pos, present, observed, rotation, 6)
    assert usable.all()
    transform = constant_velocity_transform(6, observed, extra=3)
    assert transform.shape == (4 * 6 - 4, 4 * 6 - 3 + 3)
    assert not transform[:, -3:].any()  # the attended features are dropped
    extra = torch.randn(1, 2, 3, dtype=torch.float64)  # any attended features
    mapped = torch.cat([features, extra], -1) @ transform.T  # (1, 2, F')
    assert mapped[0, 0].abs().max() < 1e-12  # constant velocity
    # the turning agent: its earlier velocities differ from the last, its accelerations not 0
    assert mapped[0, 1].abs().max() > 0.05


def test_the_zero_at_constant_velocity_form_is_kept_only_where_cross_validation_prefers_it():
    # targets linear in the transformed features (a future decided by the history's velocity
    # changes): the zero form is kept, bias exactly zero, nothing read from the attended
    # features. Targets with a base rate (every agent drifts 0.5 m/step sideways): the affine
    # map is kept.
    gen = torch.Generator().manual_seed(11)
    steps, extra, scenes, agents, num_pred = 3, 2, 40, 3, 4
    own = 4 * steps - 3
    features = torch.randn(scenes, agents, own + extra, generator=gen, dtype=torch.float64)
    transform = constant_velocity_transform(steps, 10, extra)
    mix = torch.randn(transform.shape[0], num_pred * 2, generator=gen, dtype=torch.float64)
    decided = (features @ transform.T @ mix).view(scenes, agents, num_pred, 2)
    noise = 0.01 * torch.randn(decided.shape, generator=gen, dtype=torch.float64)
    drift = torch.zeros_like(decided)
    drift[..., 1] = 0.5 * torch.arange(1, num_pred + 1, dtype=torch.float64).view(-1, 1).squeeze()
    usable = torch.ones(scenes, agents, dtype=torch.bool)
    roles = torch.zeros(scenes, agents, dtype=torch.long)
    moments = features.unsqueeze(-1) * features.unsqueeze(-2)
    subsets = [torch.ones(scenes, dtype=torch.bool)]
    for offsets, zero_kept in ((decided + noise, True), (drift + noise, False)):
        [(weight, bias, _)] = fit_highway_subsets(
            features,
            offsets.float(),
            usable,
            roles,
            1,
            num_pred,
            subsets,
            moments,
            None,
            transform,
        )
        assert (not bias.any()) == zero_kept
        if zero_kept:
            assert not weight[0, own:].any()
            constant = torch.zeros(own + extra)
            constant[2 * steps - 2] = 3.0  # the last velocity; the others' changes are zero
            for slot in range(steps - 1):
                constant[2 * slot] = 3.0
            constant[own:] = torch.randn(extra, generator=gen)
            change = torch.einsum("f,fkc->kc", constant, weight[0])
            assert change.abs().max() < 1e-5
    with pytest.raises(ValueError, match="need moments"):
        fit_highway_subsets(
            features, drift, usable, roles, 1, num_pred, subsets, None, None, transform
        )
