"""The attended highway (ModelConfig.highway_attended): the closed-form refit on the attention
and its per-edge, per-relation, per-kind and per-role-group maps. The role switches of the
attention that feeds it: test_role_attention.py."""

from __future__ import annotations

import pytest
import torch
from test_highway import ANCHORED, SMALL, accelerating_scenes

from predictor.config import ModelConfig
from predictor.highway import (
    edge_relations,
    relation_slots,
    uniform_attention,
)
from predictor.model import SmoothAttentionPredictor

torch.set_num_threads(1)


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
    first = model.highway.attended_weight.clone()
    with torch.no_grad():  # another attention, another fit of the same scenes
        model.attention.f_attn.weight.mul_(5.0)
    model.refit_attended(train, valid, num_observed)
    assert (model.highway.attended_weight - first).abs().max() > 1e-4
    # training scenes roll out with the maps fitted without their fold, as the plain highway
    scenes = torch.arange(30)
    out = model(train, valid, num_observed, sample=False, scenes=scenes).rollout.mean
    full = model.predict(train, valid, num_observed).rollout.mean
    assert (out - full).abs().max() > 1e-5
    highway = model.highway
    with torch.no_grad():  # the fold maps made equal to the full ones: the same rollout
        highway.attended_fold_weight.copy_(
            highway.attended_weight.expand_as(highway.attended_fold_weight)
        )
        highway.highway_fold_weight.copy_(
            highway.highway_weight.expand_as(highway.highway_fold_weight)
        )
        highway.highway_fold_bias.copy_(highway.highway_bias.expand_as(highway.highway_fold_bias))
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
        assert model.highway.num_maps == (4 if relation else 2)
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
    edges, mask = model.highway.neighbour_features(steps_in)
    first, second = torch.zeros_like(mask, dtype=torch.float), torch.zeros_like(mask).float()
    first[..., 0], second[..., 1] = 1.0, 1.0  # one-hot on each agent's first or second edge
    with torch.no_grad():
        anchor_std = model.head.anchor_std
        alone = [model.highway(steps_in, theta, anchor_std) for theta in (first, second)]
        mixed = model.highway(steps_in, 0.3 * first + 0.7 * second, anchor_std)
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
    assert oracle.highway.num_maps == 8  # 2 groups x 2 attended groups x 2 relations
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
                model.attention.f_attn.weight.zero_()
            model.fit_normalisation(data, valid, num_observed, roles)
            model.refit_attended(data, valid, num_observed, None, roles)
            steps_in = model._prepare(test, test_valid, num_observed, test_labels, test_roles)
            _, mask = model.highway.neighbour_features(steps_in)
            pair = torch.zeros_like(mask, dtype=torch.float)
            pair[:, :, 0] = 1.0  # cars 0 and 1: edge 0 is the other one of the pair
            with torch.no_grad():
                changes = model.highway(steps_in, pair, model.head.anchor_std)
                readings[head_groups, name] = changes[:, :2]
    torch.testing.assert_close(readings[True, "original"], readings[True, "moved"])
    difference = (readings[False, "original"] - readings[False, "moved"]).abs().max()
    assert difference > 1e-3
    with pytest.raises(ValueError, match="highway_head_groups needs attended_fit"):
        ModelConfig(**ORACLE_REFIT, num_roles=2, highway_relation=True, highway_head_groups=True)
