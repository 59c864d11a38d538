"""The linear autoregressive highway (ModelConfig.highway_steps): its closed-form fit, and the
untrained model's rollout with it against closed-form kinematics."""

from __future__ import annotations

import math

import pytest
import torch

from predictor.agent_frame import agent_frames
from predictor.config import ModelConfig, make_configs
from predictor.highway import (
    CROSS_FIT_FOLDS,
    HIGHWAY_ALPHAS,
    attended_changes,
    change_bounds,
    edge_relations,
    fit_cross_fitted,
    fit_highway,
    fit_highway_subsets,
    fold_of,
    future_offsets,
    history_features,
    neighbour_features,
    relation_slots,
    uniform_attention,
    velocity_changes,
)
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import edge_index

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
    largest = torch.maximum(-model.highway_low, model.highway_high)[0].norm(dim=-1)  # (12,)
    limit = torch.cat([largest, largest[-1:].expand(steps - num_observed - 12)])
    assert (change <= limit.view(1, -1, 1) + 1e-4).all()
    assert largest.max() < 1.0  # [m/step]: the training scenes' changes are small
    # a checkpoint without the range (written before it existed) loads unbounded
    state = {
        k: v for k, v in model.state_dict().items() if k not in ("highway_low", "highway_high")
    }
    old = SmoothAttentionPredictor(config)
    old.load_state_dict(old.fill_unclamped_range(state))
    assert old.highway_high.isinf().all() and (old.highway_low == -math.inf).all()
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
    weight = torch.randn(model.attended_weight.shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():  # a random map leaves the fitted range; the range is tested apart
        model.highway_low.fill_(-math.inf)
        model.highway_high.fill_(math.inf)

    def first_step_shift() -> torch.Tensor:
        """What the map moves the first predicted position by (the network's part cancels)."""
        with torch.no_grad():
            model.attended_weight.copy_(weight)
            moved = model.predict(train, valid, num_observed)
            model.attended_weight.zero_()
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
            model.attended_mean,
            model.attended_std,
            weight[0].expand(20, 3, -1, -1, -1),
        )[:, :, 0]
        * model.anchor_std
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
        model.f_attn.weight.mul_(3.0)
    other, other_theta = first_step_shift()
    assert (other_theta - theta).abs().max() > 1e-3
    assert (other - shift).abs().max() > 1e-4
    loss = model(train, valid, num_observed, sample=False).rollout.mean.square().sum()
    loss.backward()
    assert model.attended_weight.grad.abs().sum() > 0  # trained by the rollout's loss


def test_attended_highway_needs_the_highway_and_s_attn_drops_it():
    with pytest.raises(ValueError, match="highway_attended needs highway_steps"):
        ModelConfig(**ANCHORED, highway_attended=True)
    model, _ = make_configs("s_attn", {"highway_attended": True}, preset="agent")
    assert not model.highway_attended and model.highway_steps == 0


def follower_scenes(batch: int, steps: int, num_observed: int, seed: int):
    """Three agents heading +x. The leader (agent 1) accelerates at a constant random rate
    from the start; the follower (agent 0) drives at constant speed through the observed steps
    and then copies the leader's acceleration, so its future offset from constant velocity is
    a_L k (k + 1) / 2 after k steps: linear in the leader's observed velocities, invisible in
    its own. Agent 2 accelerates at a rate of its own. Labels: the follower attends the leader,
    the others nobody."""
    gen = torch.Generator().manual_seed(seed)
    t = torch.arange(steps, dtype=torch.float64).view(1, -1, 1)  # (1, T, 1)
    start = torch.tensor([[0.0, 0.0], [15.0, 3.5], [-10.0, -3.5]], dtype=torch.float64)
    start = start + torch.rand(batch, 3, 2, generator=gen, dtype=torch.float64)  # (B, N, 2)
    speed = 2.0 + torch.rand(batch, 3, generator=gen, dtype=torch.float64)  # (B, N) along x
    accel = 0.05 * torch.randn(batch, 3, 2, generator=gen, dtype=torch.float64)  # (B, N, 2)
    accel[:, 0] = accel[:, 1]  # the follower's, from T_obs - 1 on
    since = (t - (num_observed - 1)).clamp(min=0)  # (1, T, 1): the follower's clock
    clock = torch.cat([since, t, t], -1).unsqueeze(-1)  # (1, T, N, 1) per agent
    velocity = torch.stack([speed, torch.zeros_like(speed)], -1).unsqueeze(1)  # (B, 1, N, 2)
    positions = start.unsqueeze(1) + velocity * t.unsqueeze(-1) + accel.unsqueeze(1) * clock**2 / 2
    valid = torch.ones(batch, steps, 3, dtype=torch.bool)
    labels = torch.full((batch, steps, 3), -1, dtype=torch.long)
    labels[:, :, 0] = 1
    return positions.float(), valid, labels


REFIT = {**SMALL, **ANCHORED, "highway_steps": 4, "highway_horizon": 6}
ORACLE_REFIT = {
    **REFIT,
    "attention_mode": "oracle",
    "highway_attended": True,
    "attended_refit": True,
}


def test_refit_with_the_labelled_leader_rolls_out_the_follower_that_copies_it():
    num_observed, steps = 8, 14
    train, valid, labels = follower_scenes(batch=40, steps=steps, num_observed=num_observed, seed=1)
    test, test_valid, test_labels = follower_scenes(5, steps, num_observed, seed=2)
    truth = test[:, num_observed:, 0]  # (B, T_pred, 2) the follower
    # one map per role: the follower's future reads the leader, the others' their own history
    config = ModelConfig(
        **REFIT, attention_mode="oracle", num_roles=3, highway_attended=True, attended_refit=True
    )
    roles = torch.arange(3).expand(40, 3)
    test_roles = roles[:5]
    model = SmoothAttentionPredictor(config)
    model.fit_normalisation(train, valid, num_observed, roles)

    def follower(m: SmoothAttentionPredictor) -> torch.Tensor:
        out = m.predict(test, test_valid, num_observed, test_labels, roles=test_roles)
        return out.rollout.mean[:, :, 0]

    own_only = follower(model)
    model.refit_attended(train, valid, num_observed, labels, roles)
    refitted = follower(model)
    own_error = (own_only - truth).norm(dim=-1).max()
    assert own_error > 0.05  # the own history cannot tell the leader's acceleration [m]
    assert (refitted - truth).norm(dim=-1).max() < 0.02 * own_error
    # the maps are buffers (fitted, not trained) and travel with the checkpoint
    names = {name for name, _ in model.named_parameters()}
    assert not names & {"attended_weight", "attended_fold_weight", "highway_weight"}
    clone = SmoothAttentionPredictor(config)
    clone.load_state_dict(model.state_dict())
    torch.testing.assert_close(follower(clone), refitted)


def test_per_edge_fit_equals_the_mean_fit_under_one_hot_attention():
    num_observed, steps = 8, 14
    train, valid, labels = follower_scenes(batch=30, steps=steps, num_observed=num_observed, seed=4)
    test, test_valid, test_labels = follower_scenes(5, steps, num_observed, seed=6)
    roles = torch.arange(3).expand(30, 3)
    followers = []
    for fit in ("mean", "edges"):
        config = ModelConfig(**ORACLE_REFIT, num_roles=3, attended_fit=fit)
        model = SmoothAttentionPredictor(config)
        model.fit_normalisation(train, valid, num_observed, roles)
        model.refit_attended(train, valid, num_observed, labels, roles)
        out = model.predict(test, test_valid, num_observed, test_labels, roles=roles[:5])
        followers.append(out.rollout.mean[:, :, 0])
    # the follower attends the leader alone (the oracle attention is uniform for the others);
    # the noise-free fit is ill-conditioned, so the maps may differ where the data is flat
    torch.testing.assert_close(followers[1], followers[0], atol=1e-3, rtol=0)  # [m]
    with pytest.raises(ValueError, match="attended_fit"):
        ModelConfig(**REFIT, highway_attended=True, attended_fit="edges")  # no refit
    with pytest.raises(ValueError, match="attended_fit"):
        ModelConfig(**ORACLE_REFIT, attended_fit="sum")


def test_per_edge_maps_reward_attending_the_car_that_decides_and_mean_maps_do_not():
    """Fitted under uniform attention, the mean fit rescales the leader's half of the average,
    so attending to the leader alone then overshoots; the per-edge map is a per-neighbour
    reading that attending to the leader makes better."""
    num_observed, steps = 8, 14
    train, valid, labels = follower_scenes(batch=40, steps=steps, num_observed=num_observed, seed=5)
    roles = torch.arange(3).expand(40, 3)
    truth = train[:, num_observed:, 0]  # (B, T_pred, 2) the follower
    errors = {}
    for fit in ("mean", "edges"):
        uniform = ModelConfig(**ORACLE_REFIT, num_roles=3, attended_fit=fit)
        uniform = ModelConfig(**{**uniform.__dict__, "attention_mode": "uniform"})
        model = SmoothAttentionPredictor(uniform)
        model.fit_normalisation(train, valid, num_observed, roles)
        model.refit_attended(train, valid, num_observed, roles=roles)  # uniform attention
        oracle = SmoothAttentionPredictor(
            ModelConfig(**{**uniform.__dict__, "attention_mode": "oracle"})
        )
        oracle.load_state_dict(model.state_dict())  # the same maps, attention on the leader
        for name, m in (("uniform", model), ("leader", oracle)):
            out = m.predict(train, valid, num_observed, labels, roles=roles).rollout.mean[:, :, 0]
            errors[fit, name] = (out - truth).norm(dim=-1).mean().item()
    assert errors["edges", "leader"] < 0.9 * errors["edges", "uniform"]  # measured 0.32, 0.40
    assert errors["mean", "leader"] > 2 * errors["mean", "uniform"]  # measured 1.19, 0.31


def test_refit_reads_the_current_attention_and_cross_fits_the_training_scenes():
    num_observed, steps = 8, 14
    train, valid, _ = follower_scenes(batch=30, steps=steps, num_observed=num_observed, seed=3)
    config = ModelConfig(**REFIT, highway_attended=True, attended_refit=True)
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(config)
    model.fit_normalisation(train, valid, num_observed)
    model.refit_attended(train, valid, num_observed)
    first = model.attended_weight.clone()
    with torch.no_grad():  # another attention, another fit of the same scenes
        model.f_attn.weight.mul_(5.0)
    model.refit_attended(train, valid, num_observed)
    assert (model.attended_weight - first).abs().max() > 1e-4
    # training scenes roll out with the maps fitted without their fold, as the plain highway
    scenes = torch.arange(30)
    out = model(train, valid, num_observed, sample=False, scenes=scenes).rollout.mean
    full = model.predict(train, valid, num_observed).rollout.mean
    assert (out - full).abs().max() > 1e-5
    with torch.no_grad():  # the fold maps made equal to the full ones: the same rollout
        model.attended_fold_weight.copy_(
            model.attended_weight.expand_as(model.attended_fold_weight)
        )
        model.highway_fold_weight.copy_(model.highway_weight.expand_as(model.highway_fold_weight))
        model.highway_fold_bias.copy_(model.highway_bias.expand_as(model.highway_fold_bias))
    same = model(train, valid, num_observed, sample=False, scenes=scenes).rollout.mean
    torch.testing.assert_close(same, full)


def test_attended_refit_needs_the_attended_highway():
    with pytest.raises(ValueError, match="attended_refit needs highway_attended"):
        ModelConfig(**REFIT, attended_refit=True)
    model = SmoothAttentionPredictor(ModelConfig(**REFIT, highway_attended=True))
    positions, valid = accelerating_scenes(batch=2, steps=10, agents=3)
    with pytest.raises(ValueError, match="needs ModelConfig.attended_refit"):
        model.refit_attended(positions, valid, 8)


def mirrored_pair_scenes(batch: int, steps: int, num_observed: int, seed: int):
    """Two cars of one role heading +x, one 15 m ahead of the other (which one varies by
    scene), and a third car of another role. Every car accelerates at a constant random rate
    over the observed steps; from T_obs - 1 on the rear car takes the front car's acceleration
    and the front car the negative of the rear car's. The same role reads the other car with
    opposite signs depending on which is ahead. Labels: the two cars attend each other."""
    gen = torch.Generator().manual_seed(seed)
    t = torch.arange(steps, dtype=torch.float64).view(1, -1, 1, 1)  # (1, T, 1, 1)
    front_is_0 = torch.rand(batch, generator=gen) < 0.5  # (B,)
    x0 = torch.where(front_is_0, 15.0, 0.0).double()
    start = torch.zeros(batch, 3, 2, dtype=torch.float64)
    start[:, 0, 0], start[:, 1, 0], start[:, 1, 1] = x0, 15.0 - x0, 3.5
    start[:, 2] = torch.tensor([-20.0, -3.5], dtype=torch.float64)
    speed = 2.0 + torch.rand(batch, 3, generator=gen, dtype=torch.float64)
    velocity = torch.stack([speed, torch.zeros_like(speed)], -1)  # (B, N, 2)
    accel = 0.05 * torch.randn(batch, 3, 2, generator=gen, dtype=torch.float64)  # observed
    later = accel.clone()  # from T_obs - 1 on
    sign = torch.where(front_is_0, -1.0, 1.0).double().view(-1, 1)  # car 0 reads car 1 so
    later[:, 0], later[:, 1] = sign * accel[:, 1], -sign * accel[:, 0]
    knee = num_observed - 1
    before, after = t.clamp(max=knee), (t - knee).clamp(min=0)  # (1, T, 1, 1)
    v_knee = velocity.unsqueeze(1) + accel.unsqueeze(1) * knee
    positions = torch.where(
        t <= knee,
        start.unsqueeze(1) + velocity.unsqueeze(1) * before + accel.unsqueeze(1) * before**2 / 2,
        start.unsqueeze(1)
        + velocity.unsqueeze(1) * knee
        + accel.unsqueeze(1) * knee**2 / 2
        + v_knee * after
        + later.unsqueeze(1) * after**2 / 2,
    )
    valid = torch.ones(batch, steps, 3, dtype=torch.bool)
    labels = torch.full((batch, steps, 3), -1, dtype=torch.long)
    labels[:, :, 0], labels[:, :, 1] = 1, 0
    roles = torch.tensor([0, 0, 1]).expand(batch, 3)
    return positions.float(), valid, labels, roles


def test_relation_maps_read_a_car_ahead_and_a_car_behind_differently():
    num_observed, steps = 8, 14
    train = mirrored_pair_scenes(60, steps, num_observed, seed=1)
    test = mirrored_pair_scenes(8, steps, num_observed, seed=2)
    errors = {}
    for relation in (False, True):
        config = ModelConfig(**ORACLE_REFIT, num_roles=2, highway_relation=relation)
        model = SmoothAttentionPredictor(config)
        assert model.num_maps == (4 if relation else 2)
        positions, valid, labels, roles = train
        model.fit_normalisation(positions, valid, num_observed, roles)
        model.refit_attended(positions, valid, num_observed, labels, roles)
        positions, valid, labels, roles = test
        out = model.predict(positions, valid, num_observed, labels, roles=roles).rollout.mean
        truth = positions[:, num_observed:, :2]
        errors[relation] = (out[:, :, :2] - truth).norm(dim=-1).max()
    # one map per role must average the two readings; per relation each is exact
    assert errors[False] > 0.05
    assert errors[True] < 0.05 * errors[False]


def test_relation_slots_follow_the_attention_weighted_position():
    roles = torch.tensor([[0, 1, 1]])
    features = torch.zeros(1, 3, 2, 4)
    features[0, 0, :, 0] = torch.tensor([5.0, -1.0])  # agent 0: one ahead, one behind
    features[0, 1, :, 0] = torch.tensor([-2.0, -3.0])  # agent 1: both behind
    features[0, 2, :, 0] = torch.tensor([4.0, 1.0])  # agent 2: both ahead, one masked
    mask = torch.tensor([[[True, True], [True, True], [False, True]]])
    theta = torch.tensor([[[0.1, 0.9], [0.5, 0.5], [0.0, 1.0]]])
    # agent 0: 0.1 * 5 - 0.9 * 1 < 0: behind; agent 1 behind; agent 2: 1.0 * 1 > 0: ahead
    assert relation_slots(roles, theta, features, mask).tolist() == [[1, 3, 2]]
    uniform = uniform_attention(mask)
    assert uniform.tolist() == [[[0.5, 0.5], [0.5, 0.5], [0.0, 1.0]]]
    # uniform: agent 0 sees 2 > 0 ahead
    assert relation_slots(roles, uniform, features, mask).tolist() == [[0, 3, 2]]


# the attended highway with each edge read by its own relation's map, two roles
EDGE_RELATIONS = {
    **REFIT,
    "highway_attended": True,
    "attended_refit": True,
    "num_roles": 2,
    "highway_relation": True,
    "attended_fit": "edge_relations",
}


def fit_and_read_the_pair_exactly(model, positions, valid, labels, roles, num_observed: int):
    """Fit the model's highway on the mirrored pair scenes and check that it predicts 8 fresh
    ones (seed 2) to 5 cm under its attention; returns their (positions, valid, labels, roles)."""
    model.fit_normalisation(positions, valid, num_observed, roles)
    model.refit_attended(positions, valid, num_observed, labels, roles)
    test = mirrored_pair_scenes(8, positions.shape[1], num_observed, 2)
    out = model.predict(test[0], test[1], num_observed, test[2], roles=test[3])
    truth = test[0][:, num_observed:, :2]
    assert (out.rollout.mean[:, :, :2] - truth).norm(dim=-1).max() < 0.05
    return test


def test_edge_relations_split_the_attention_by_each_edges_own_side():
    groups = torch.tensor([[0, 1, 1]])
    features = torch.zeros(1, 3, 2, 2)
    features[0, 0, :, 0] = torch.tensor([5.0, -1.0])  # agent 0: one ahead, one behind
    features[0, 0, :, 1] = torch.tensor([2.0, 4.0])
    features[0, 1, :, 0] = torch.tensor([-2.0, -3.0])  # agent 1: both behind
    features[0, 2, :, 0] = torch.tensor([4.0, 1.0])  # agent 2: no usable edge
    mask = torch.tensor([[[True, True], [True, True], [False, False]]])
    theta = torch.tensor([[[0.25, 0.75], [0.5, 0.5], [0.6, 0.4]]])
    mean, std = torch.zeros(2), torch.tensor([1.0, 2.0])
    slots, masses, attended, second = edge_relations(groups, theta, features, mask, mean, std)
    assert slots.tolist() == [[[0, 2, 2]], [[1, 3, 3]]]  # (ahead, behind) x 2 x group
    assert masses.tolist() == [[[0.25, 0.0, 0.0]], [[0.75, 1.0, 1.0]]]
    z = features / std  # standardised
    torch.testing.assert_close(attended[0, 0, 0], z[0, 0, 0])  # the car ahead alone
    torch.testing.assert_close(attended[1, 0, 0], z[0, 0, 1])  # the car behind alone
    torch.testing.assert_close(attended[1, 0, 1], z[0, 1].mean(0))  # both behind, equal shares
    torch.testing.assert_close(attended[1, 0, 2], torch.zeros(2))  # nothing usable: zeros
    expected = 0.5 * (torch.outer(z[0, 1, 0], z[0, 1, 0]) + torch.outer(z[0, 1, 1], z[0, 1, 1]))
    torch.testing.assert_close(second[1, 0, 1], expected)
    torch.testing.assert_close(second[0, 0, 0], torch.outer(z[0, 0, 0], z[0, 0, 0]))


def test_edge_relations_split_by_the_attended_kind_too():
    """With kinds (the attended agent's group), each (kind, side) part holds only its edges:
    agent 0 has a kind-0 car ahead, a kind-1 car ahead and a kind-1 car behind."""
    groups = torch.tensor([[1, 0, 1, 1]])
    features = torch.zeros(1, 4, 3, 2)
    features[0, 0, :, 0] = torch.tensor([5.0, 3.0, -1.0])
    features[0, 0, :, 1] = torch.tensor([2.0, 4.0, 6.0])
    mask = torch.ones(1, 4, 3, dtype=torch.bool)
    mask[0, 1:] = False  # only agent 0 has usable edges
    kinds = torch.tensor([[[0, 1, 1], [1, 1, 1], [0, 1, 1], [0, 1, 1]]])
    theta = torch.tensor([[[0.5, 0.2, 0.3], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    mean, std = torch.zeros(2), torch.ones(2)
    slots, masses, attended, second = edge_relations(
        groups, theta, features, mask, mean, std, kinds, 2
    )
    # parts: kind 0 ahead, kind 0 behind, kind 1 ahead, kind 1 behind; 4 per group
    assert slots[:, 0, 0].tolist() == [4, 5, 6, 7] and slots[:, 0, 1].tolist() == [0, 1, 2, 3]
    torch.testing.assert_close(masses[:, 0, 0], torch.tensor([0.5, 0.0, 0.2, 0.3]))
    assert masses[:, 0, 1].tolist() == [0.0, 1.0, 0.0, 0.0]  # no usable edge: kind 0 behind
    for part, edge in ((0, 0), (2, 1), (3, 2)):  # each part holds one edge
        torch.testing.assert_close(attended[part, 0, 0], features[0, 0, edge])
        torch.testing.assert_close(
            second[part, 0, 0], torch.outer(features[0, 0, edge], features[0, 0, edge])
        )
    # one kind: the two-part split of before
    slots_one, masses_one, _, _ = edge_relations(groups, theta, features, mask, mean, std)
    torch.testing.assert_close(masses_one[:, 0, 0], torch.tensor([0.7, 0.3]))
    assert slots_one[:, 0, 0].tolist() == [2, 3]


def test_edge_relation_maps_read_each_side_exactly_and_mix_by_the_attention():
    """Under the labelled attention the per-edge-relation fit reads the mirrored pair exactly
    (as the per-agent relation does); the rollout's change under mixed attention is the mix of
    each side's reading where an agent's edges lie on both sides."""
    num_observed, steps = 8, 14
    positions, valid, labels, roles = mirrored_pair_scenes(60, steps, num_observed, seed=1)
    config = ModelConfig(
        **ORACLE_REFIT, num_roles=2, highway_relation=True, attended_fit="edge_relations"
    )
    model = SmoothAttentionPredictor(config)
    test, test_valid, test_labels, test_roles = fit_and_read_the_pair_exactly(
        model, positions, valid, labels, roles, num_observed
    )
    steps_in = model._prepare(test, test_valid, num_observed, test_labels, test_roles)
    edges, mask = model._neighbour_features(steps_in)
    first, second = torch.zeros_like(mask, dtype=torch.float), torch.zeros_like(mask).float()
    first[..., 0], second[..., 1] = 1.0, 1.0  # one-hot on each agent's first or second edge
    with torch.no_grad():
        alone = [model._highway(steps_in, theta) for theta in (first, second)]
        mixed = model._highway(steps_in, 0.3 * first + 0.7 * second)
    both_sides = (edges[..., 0, 0] > 0) != (edges[..., 1, 0] > 0)  # (B, N)
    assert both_sides.sum() >= 8
    expected = 0.3 * alone[0] + 0.7 * alone[1]
    torch.testing.assert_close(mixed[both_sides], expected[both_sides])
    with pytest.raises(ValueError, match="edge_relations' needs highway_relation"):
        ModelConfig(**ORACLE_REFIT, num_roles=2, attended_fit="edge_relations")


def test_head_groups_keep_the_other_kinds_edges_out_of_a_map():
    """highway_head_groups: maps per (group, attended group, relation). The mirrored pair is
    still read exactly under the labelled attention. Under learned attention shared equally by
    the pair and the third car (another role; behind both, so on the front car's side), the
    maps that read the pair are fitted on the pair's edges alone: changing the third car's
    motion leaves the pair's reading of each other unchanged; without head groups it does not."""
    num_observed, steps = 8, 14
    positions, valid, labels, roles = mirrored_pair_scenes(60, steps, num_observed, seed=1)
    common = EDGE_RELATIONS
    oracle = SmoothAttentionPredictor(
        ModelConfig(**common, attention_mode="oracle", highway_head_groups=True)
    )
    assert oracle.num_maps == 8  # 2 groups x 2 attended groups x 2 relations
    test, test_valid, test_labels, test_roles = fit_and_read_the_pair_exactly(
        oracle, positions, valid, labels, roles, num_observed
    )

    gen = torch.Generator().manual_seed(3)
    t = torch.arange(steps, dtype=torch.float32).view(1, -1, 1)
    moved = positions.clone()  # the third car with another acceleration in every scene
    moved[:, :, 2] += 0.05 * torch.randn(60, 1, 2, generator=gen) * t**2
    readings = {}
    for head_groups in (True, False):
        for name, data in (("original", positions), ("moved", moved)):
            torch.manual_seed(0)
            model = SmoothAttentionPredictor(ModelConfig(**common, highway_head_groups=head_groups))
            with torch.no_grad():  # learned attention with zero scores: equal shares
                model.f_attn.weight.zero_()
            model.fit_normalisation(data, valid, num_observed, roles)
            model.refit_attended(data, valid, num_observed, None, roles)
            steps_in = model._prepare(test, test_valid, num_observed, test_labels, test_roles)
            _, mask = model._neighbour_features(steps_in)
            pair = torch.zeros_like(mask, dtype=torch.float)
            pair[:, :, 0] = 1.0  # cars 0 and 1: edge 0 is the other one of the pair
            with torch.no_grad():
                readings[head_groups, name] = model._highway(steps_in, pair)[:, :2]
    torch.testing.assert_close(readings[True, "original"], readings[True, "moved"])
    difference = (readings[False, "original"] - readings[False, "moved"]).abs().max()
    assert difference > 1e-3
    with pytest.raises(ValueError, match="highway_head_groups needs attended_fit"):
        ModelConfig(**ORACLE_REFIT, num_roles=2, highway_relation=True, highway_head_groups=True)


def test_refit_on_prior_fits_with_the_role_balanced_attention_whatever_was_learned():
    """refit_on_prior: the maps are those of a refit under the learned attention's prior,
    which a learned attention with zero scores gives (equal shares per role with
    role_balanced_attention); changing the learned scores leaves them as they were."""
    num_observed, steps = 8, 14
    positions, valid, _, _ = mirrored_pair_scenes(30, steps, num_observed, seed=8)
    positions = torch.cat([positions, positions[:, :, 2:] + torch.tensor([5.0, 0.0])], 2)
    valid = torch.ones(positions.shape[:3], dtype=torch.bool)
    roles = torch.tensor([0, 0, 1, 1]).expand(30, 4)  # two of each role: the balance matters
    common = {
        **EDGE_RELATIONS,
        "highway_head_groups": True,
        "role_balanced_attention": True,
    }
    buffers = ("highway_weight", "highway_bias", "attended_weight", "highway_low")
    fitted = {}
    for name, prior, scale in (("zero", False, 0.0), ("prior", True, 3.0), ("moved", True, -2.0)):
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(ModelConfig(**common, refit_on_prior=prior))
        with torch.no_grad():
            model.f_attn.weight.normal_(0.0, 1.0).mul_(scale)
        model.fit_normalisation(positions, valid, num_observed, roles)
        model.refit_attended(positions, valid, num_observed, None, roles)
        fitted[name] = [getattr(model, b).clone() for b in buffers]
        steps_in = model._prepare(positions, valid, num_observed, None, roles)
        if name == "zero":  # zero scores: the role-balanced prior (a third per role pair...)
            with torch.no_grad():
                theta = model._block(steps_in, 0, num_observed, None).attention[-1]
            torch.testing.assert_close(theta, model._prior_attention(steps_in))
            # agent 0 (role 0) sees one role-0 car (1/2) and two role-1 cars (1/4 each)
            torch.testing.assert_close(theta[0, 0], torch.tensor([0.5, 0.25, 0.25]))
    for got, want in zip(fitted["prior"], fitted["zero"]):
        torch.testing.assert_close(got, want)
    for got, want in zip(fitted["moved"], fitted["zero"]):
        torch.testing.assert_close(got, want)
    with pytest.raises(ValueError, match="refit_on_prior needs attended_refit"):
        ModelConfig(**REFIT, refit_on_prior=True)


def test_role_groups_pool_the_maps_of_roles_that_behave_alike():
    """Two cars of *different* roles in the mirrored pair: pooled in one group they share
    each relation's maps (4 maps instead of 6), fitted on both cars' scenes, and each relation
    is still read exactly."""
    num_observed, steps = 8, 14
    positions, valid, labels, _ = mirrored_pair_scenes(40, steps, num_observed, seed=5)
    roles = torch.tensor([0, 1, 2]).expand(40, 3)
    maps = {}
    for groups in ("", "0,0,1"):
        config = ModelConfig(
            **ORACLE_REFIT, num_roles=3, highway_relation=True, highway_role_groups=groups
        )
        model = SmoothAttentionPredictor(config)
        assert model.num_maps == (6 if not groups else 4)
        model.fit_normalisation(positions, valid, num_observed, roles)
        model.refit_attended(positions, valid, num_observed, labels, roles)
        maps[groups] = model.highway_weight.clone()
        out = model.predict(positions, valid, num_observed, labels, roles=roles).rollout.mean
        truth = positions[:, num_observed:, :2]
        assert (out[:, :, :2] - truth).norm(dim=-1).max() < 0.05  # each relation read exactly
    assert maps["0,0,1"].shape[0] == 4 and maps[""].shape[0] == 6
    with pytest.raises(ValueError, match="2 roles' groups; the model has 3 roles"):
        SmoothAttentionPredictor(ModelConfig(**REFIT, num_roles=3, highway_role_groups="0,1"))
    for bad in ("0,2", "a,b", "0,-1"):
        with pytest.raises(ValueError, match="highway_role_groups must"):
            ModelConfig(**REFIT, num_roles=2, highway_role_groups=bad)


def test_role_attention_bias_moves_the_attention_to_a_role():
    """A large learnt bias for (role 0 attends role 1) puts role 0's attention on the role-1
    agent; zero bias leaves the scores as they were."""
    positions, valid, labels, roles = mirrored_pair_scenes(4, 10, 8, seed=6)
    roles = torch.tensor([0, 1, 2]).expand(4, 3)
    config = ModelConfig(**REFIT, num_roles=3, role_attention_bias=True)
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(config)
    assert model.role_pair.shape == (3, 3) and model.role_pair.abs().sum() == 0
    plain = ModelConfig(**REFIT, num_roles=3)
    torch.manual_seed(0)
    without = SmoothAttentionPredictor(plain)
    without.load_state_dict(
        {k: v for k, v in model.state_dict().items() if k != "role_pair"}, strict=True
    )
    before = model(positions, valid, 8, sample=False, roles=roles).attention
    torch.testing.assert_close(
        before, without(positions, valid, 8, sample=False, roles=roles).attention
    )
    with torch.no_grad():
        model.role_pair[0, 1] = 20.0
    after = model(positions, valid, 8, sample=False, roles=roles).attention  # (B, T, N, N-1)
    assert after[:, :, 0, 0].min() > 0.99  # agent 0 (role 0) attends agent 1 (its edge 0)
    torch.testing.assert_close(after[:, :, 1:], before[:, :, 1:])  # the others unchanged
    # without roles every agent is of one kind, and one bias for every pair would shift all
    # scores alike (the softmax ignores it): the model then has none
    no_roles = SmoothAttentionPredictor(ModelConfig(**REFIT, role_attention_bias=True))
    assert no_roles.role_pair is None


def test_role_balanced_attention_divides_each_weight_by_its_roles_count():
    """With role_balanced_attention the learned attention is the plain one with each weight
    divided by the number of the agent's neighbours of that role, renormalised (a softmax of
    logits minus log counts); without roles (num_roles 0) it changes nothing."""
    positions, valid, _, _ = mirrored_pair_scenes(4, 10, 8, seed=6)
    positions = torch.cat([positions, positions[:, :, 2:] + 40.0], 2)  # two role-2 agents
    valid = torch.cat([valid, valid[:, :, 2:]], 2)
    roles = torch.tensor([0, 1, 2, 2]).expand(4, 4)
    models = []
    for balanced in (False, True):
        torch.manual_seed(0)
        config = ModelConfig(**REFIT, num_roles=3, role_balanced_attention=balanced)
        models.append(SmoothAttentionPredictor(config))
    plain, balanced = (m(positions, valid, 8, sample=False, roles=roles).attention for m in models)
    counts = torch.tensor([[1.0, 2.0, 2.0], [1.0, 2.0, 2.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    expected = plain / counts  # (B, T, N, N-1): columns are the other agents in slot order
    expected = expected / expected.sum(-1, keepdim=True)
    torch.testing.assert_close(balanced, expected)
    without = []
    for balanced in (False, True):  # num_roles 0: one kind of agent, nothing to balance
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(ModelConfig(**REFIT, role_balanced_attention=balanced))
        without.append(model(positions, valid, 8, sample=False).attention)
    torch.testing.assert_close(without[0], without[1])


def test_role_bias_by_group_is_one_bias_for_every_pair_of_its_groups():
    """Roles 0 and 1 in group 0: one bias (group 0 attends group 0) puts role 0's attention on
    role 1 and role 1's on role 0, and leaves the group-1 agent's attention alone."""
    positions, valid, _, _ = mirrored_pair_scenes(4, 10, 8, seed=6)
    roles = torch.tensor([0, 1, 2]).expand(4, 3)
    grouped = {**REFIT, "num_roles": 3, "role_attention_bias": True}
    config = ModelConfig(**grouped, highway_role_groups="0,0,1", role_bias_by_group=True)
    model = SmoothAttentionPredictor(config)
    assert model.role_pair.shape == (2, 2)
    before = model(positions, valid, 8, sample=False, roles=roles).attention
    with torch.no_grad():
        model.role_pair[0, 0] = 20.0
    after = model(positions, valid, 8, sample=False, roles=roles).attention  # (B, T, N, N-1)
    assert after[:, :, 0, 0].min() > 0.99  # agent 0 attends agent 1 (agent 0's edge 0)
    assert after[:, :, 1, 0].min() > 0.99  # agent 1 attends agent 0 (agent 1's edge 0)
    torch.testing.assert_close(after[:, :, 2], before[:, :, 2])
    for missing in ({"highway_role_groups": ""}, {"role_attention_bias": False}):
        with pytest.raises(ValueError, match="role_bias_by_group needs"):
            ModelConfig(
                **{**grouped, "highway_role_groups": "0,0,1", **missing}, role_bias_by_group=True
            )
