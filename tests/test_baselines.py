"""The ridge baseline against closed-form motion: straight lines, constant acceleration in any
direction, and a future decided by another agent that only the right neighbour features reveal."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO_ROOT, tool_env

from predictor.baselines import (
    BANDED_SCALES,
    BASELINES,
    CASE_STRIDE,
    RELATION_AHEAD,
    RELATION_BEHIND,
    RIDGE_BASELINES,
    RidgeBaseline,
    RidgeConfig,
    constant_velocity,
    relation_groups,
    scene_derangement,
)
from predictor.interaction_gain import interaction_gain
from predictor.label_slots import attended_agents, attended_count
from trajectory_data.format import DatasetMeta, TrajectorySet, write_dataset

DT = 0.2
OBSERVED = 8
STEPS = 14  # 6 predicted


def kinematic_states(
    start: np.ndarray, heading: np.ndarray, speed: np.ndarray, accel: np.ndarray
) -> np.ndarray:
    """(n, T, N, 4) states of agents moving along their heading with constant acceleration:
    x(t) = x0 + (v t + a t^2 / 2) u, u the unit heading vector (closed form)."""
    t = np.arange(STEPS) * DT  # (T,)
    travel = speed[:, None] * t[None, :, None] + 0.5 * accel[:, None] * t[None, :, None] ** 2
    direction = np.stack([np.cos(heading), np.sin(heading)], -1)  # (n, N, 2)
    xy = start[:, None] + travel[..., None] * direction[:, None]  # (n, T, N, 2)
    heading_t = np.broadcast_to(heading[:, None], travel.shape)
    speed_t = speed[:, None] + accel[:, None] * t[None, :, None]
    return np.concatenate([xy, heading_t[..., None], speed_t[..., None]], -1).astype(np.float64)


def random_agents(rng: np.random.Generator, n: int, num_agents: int, accel_scale: float):
    start = rng.uniform(-50, 50, (n, num_agents, 2))
    heading = rng.uniform(-np.pi, np.pi, (n, num_agents))
    speed = rng.uniform(5, 15, (n, num_agents))
    accel = rng.uniform(-accel_scale, accel_scale, (n, num_agents))
    return kinematic_states(start, heading, speed, accel)


def fitted(states, roles, config=RidgeConfig(), attention=None, valid=None):
    valid = np.ones(states.shape[:3], bool) if valid is None else valid
    attention = np.full(states.shape[:3], -1, np.int16) if attention is None else attention
    return RidgeBaseline(config).fit(states, valid, attention, roles, OBSERVED, DT)


def predict(model, states, roles, attention=None, valid=None):
    valid = np.ones(states.shape[:3], bool) if valid is None else valid
    attention = np.full(states.shape[:3], -1, np.int16) if attention is None else attention
    return model.predict(states, valid, attention, roles)


def test_baseline_names_map_to_ridge_configurations():
    assert set(BASELINES) == {"const_vel", *RIDGE_BASELINES}
    assert RidgeConfig.named("ridge_labelled").neighbours == "labelled"
    named = RidgeConfig.named("ridge_labelled_relation")
    assert (named.neighbours, named.groups) == ("labelled", "relation")
    with pytest.raises(ValueError, match="not a ridge baseline"):
        RidgeConfig.named("const_vel")
    for bad in ({"neighbours": "psychic"}, {"history_steps": 1}, {"folds": 1}, {"alphas": ()}):
        with pytest.raises(ValueError):
            RidgeConfig(**bad)


def test_constant_speed_agents_are_predicted_exactly():
    rng = np.random.default_rng(0)
    train, test = random_agents(rng, 30, 3, 0.0), random_agents(rng, 10, 3, 0.0)
    roles = np.zeros((30, 3), np.int8)
    model = fitted(train, roles)
    pred = predict(model, test, roles[:10])
    np.testing.assert_allclose(pred, test[:, OBSERVED:, :, :2], atol=1e-4)
    cv = constant_velocity(test[..., :2], np.ones(test.shape[:3], bool), OBSERVED)
    np.testing.assert_allclose(pred, cv, atol=1e-4)


def test_constant_acceleration_in_any_direction_is_learnt_from_the_history():
    """The offset from constant velocity is linear in the acceleration, which the history's
    second differences reveal; headings are random, so only an agent-centric frame makes one
    linear model fit all agents."""
    rng = np.random.default_rng(1)
    train, test = random_agents(rng, 60, 2, 2.0), random_agents(rng, 20, 2, 2.0)
    roles = np.zeros((60, 2), np.int8)
    model = fitted(train, roles, RidgeConfig(history_steps=4))
    pred = predict(model, test, roles[:20])
    truth = test[:, OBSERVED:, :, :2]
    cv = constant_velocity(test[..., :2], np.ones(test.shape[:3], bool), OBSERVED)
    cv_error = np.linalg.norm(cv - truth, axis=-1).mean()
    ridge_error = np.linalg.norm(pred - truth, axis=-1).mean()
    assert cv_error > 0.3  # not trivial: constant velocity is off by 0.46 m on average
    assert ridge_error < 2e-3 * cv_error
    assert model.history == 4


def decided_by_neighbour(rng: np.random.Generator, n: int):
    """Agent 0 drives straight, then drifts sideways in proportion to agent 1's lateral offset
    at the last observed step (as if it made room); agents 1-3 drive straight. Agent 0's label
    is agent 1 throughout, and agent 1 is its nearest neighbour."""
    states = random_agents(rng, n, 4, 0.0)
    heading = states[:, 0, 0, 2]  # (n,)
    normal = np.stack([-np.sin(heading), np.cos(heading)], -1)  # (n, 2) agent 0's left
    t0 = OBSERVED - 1
    lateral = rng.uniform(-3.0, 3.0, n)
    ahead = np.stack([np.cos(heading), np.sin(heading)], -1)
    states[:, :, 1, :2] = states[:, :, 0, :2] + (6.0 * ahead + lateral[:, None] * normal)[:, None]
    states[:, :, 1, 2:] = states[:, :, 0, 2:]
    for agent in (2, 3):  # far away
        states[:, :, agent, :2] += 200.0
    k = np.arange(1, STEPS - t0)  # steps after the last observed one
    drift = 0.05 * lateral[:, None] * k[None] ** 2  # (n, P) [m]
    states[:, t0 + 1 :, 0, :2] += drift[..., None] * normal[:, None]
    attention = np.full(states.shape[:3], -1, np.int16)
    attention[:, :, 0] = 1
    roles = np.tile(np.array([0, 1, 2, 2], np.int8), (n, 1))
    return states, attention, roles


@pytest.mark.parametrize(
    ("neighbours", "informative"),
    [
        ("none", False),
        ("random", False),
        ("shuffled", False),
        ("labelled", True),
        ("nearest", True),
    ],
)
def test_only_the_deciding_neighbour_explains_the_future(neighbours, informative):
    rng = np.random.default_rng(2)
    train, train_attention, train_roles = decided_by_neighbour(rng, 80)
    test, test_attention, test_roles = decided_by_neighbour(rng, 30)
    config = RidgeConfig(history_steps=4, neighbours=neighbours)
    model = fitted(train, train_roles, config, train_attention)
    pred = predict(model, test, test_roles, test_attention)
    error = np.linalg.norm(pred[:, :, 0] - test[:, OBSERVED:, 0, :2], axis=-1).mean()
    if informative:
        assert error < 0.01
    else:  # the drift's sign and size are unknowable: the error stays near the drift itself
        assert error > 0.3


def decided_by_two_in_turn(rng: np.random.Generator, n: int):
    """As `decided_by_neighbour`, but agent 0's drift is the sum of agent 1's and agent 2's
    lateral offsets (each beside it at its own distance ahead), and its label moves: agent 1
    for the first 9 steps, agent 2 for the last 5 (agent 3, far away, is the distractor)."""
    states, attention, roles = decided_by_neighbour(rng, n)
    heading = states[:, 0, 0, 2]
    normal = np.stack([-np.sin(heading), np.cos(heading)], -1)
    ahead = np.stack([np.cos(heading), np.sin(heading)], -1)
    lateral = rng.uniform(-3.0, 3.0, n)
    states[:, :, 2, :2] = states[:, :, 0, :2] + (12.0 * ahead + lateral[:, None] * normal)[:, None]
    states[:, :, 2, 2:] = states[:, :, 0, 2:]
    k = np.arange(1, STEPS - OBSERVED + 1)
    states[:, OBSERVED:, 0, :2] += (0.05 * lateral[:, None] * k[None] ** 2)[..., None] * normal[
        :, None
    ]
    attention[:, 9:, 0] = 2
    roles[:, 2] = 1  # agents 1 and 2 share a role; agent 3 is the only role-2 agent
    return states, attention, roles


def test_attended_agents_lists_the_most_attended_then_the_others_in_order():
    attention = np.full((2, 6, 3), -1, np.int16)
    attention[0, :, 0] = [1, 1, 2, 2, 2, -1]  # most: 2 (3 steps), then 1
    attention[0, :, 1] = [-1, 0, 0, -1, -1, -1]
    attention[1, :, 2] = [0, 1, 0, 1, -1, 1]  # 1 (3 steps) before 0 (2 steps)
    np.testing.assert_array_equal(attended_count(attention), [[2, 1, 0], [0, 0, 2]])
    slots = attended_agents(attention, 2)
    np.testing.assert_array_equal(slots[0], [[2, 0, -1], [-1, -1, 1]])
    np.testing.assert_array_equal(slots[1], [[1, -1, -1], [-1, -1, 0]])


def test_moving_labels_give_every_named_agent_a_slot_and_the_control_draws_distractors():
    """Agent 0's future needs both agents its label names in turn: the labelled ridge reads
    both (two slots) and explains it; a random role-2 agent (the distractor) explains nothing,
    and the control never draws another role."""
    rng = np.random.default_rng(3)
    train, train_attention, train_roles = decided_by_two_in_turn(rng, 120)
    test, test_attention, test_roles = decided_by_two_in_turn(rng, 30)

    def error(config):
        model = fitted(train, train_roles, config, train_attention)
        assert model.label_slots == 2
        pred = predict(model, test, test_roles, test_attention)
        return np.linalg.norm(pred[:, :, 0] - test[:, OBSERVED:, 0, :2], axis=-1).mean()

    assert error(RidgeConfig(history_steps=4, neighbours="labelled")) < 0.01
    control = RidgeConfig(history_steps=4, neighbours="random", random_role=2)
    assert error(control) > 0.3
    model = fitted(train, train_roles, control, train_attention)
    valid = np.ones(test.shape[:3], bool)
    drawn = model._neighbours(test[:, OBSERVED - 1, :, :2], valid[:, 0], test_attention, test_roles)
    assert len(drawn) == 2
    assert set(np.unique(drawn[0][:, :3])) == {3}  # the distractor, for agents 0-2
    assert (drawn[1][:, :3] == -1).all()  # no second distractor to draw
    with pytest.raises(ValueError, match="random_role needs the agents' roles"):
        model._neighbours(test[:, OBSERVED - 1, :, :2], valid[:, 0], test_attention)


def test_shuffled_neighbour_is_the_labelled_car_of_another_scene():
    """The null control's features are the labelled ones moved by a derangement: every scene
    gets another scene's, the same for the same seed, and the own features are untouched."""
    order = scene_derangement(7, seed=3)
    assert sorted(order) == list(range(7)) and (order != np.arange(7)).all()
    assert (scene_derangement(7, seed=3) == order).all()
    assert (scene_derangement(7, seed=4) != order).any()
    with pytest.raises(ValueError, match="at least two scenes"):
        scene_derangement(1, seed=0)

    states, attention, roles = decided_by_neighbour(np.random.default_rng(4), 7)
    valid = np.ones(states.shape[:3], bool)
    labelled = fitted(states, roles, RidgeConfig(history_steps=4, neighbours="labelled"), attention)
    shuffled_config = RidgeConfig(history_steps=4, neighbours="shuffled", seed=3)
    shuffled = fitted(states, roles, shuffled_config, attention)
    own = labelled.own_features
    theirs, _, _ = labelled.features(states, valid, attention)
    moved, _, _ = shuffled.features(states, valid, attention)
    np.testing.assert_array_equal(moved[:, :, :own], theirs[:, :, :own])
    np.testing.assert_array_equal(moved[:, :, own:], theirs[order, :, own:])
    assert not np.array_equal(moved[:, :, own:], theirs[:, :, own:])


def test_banded_penalty_can_drop_a_neighbour_and_keeps_a_deciding_one():
    """A neighbour scale of 0 is the own-history fit exactly (the block's columns vanish); with
    the banded grid the labelled car that decides the future keeps a nonzero scale."""
    rng = np.random.default_rng(2)
    train, train_attention, train_roles = decided_by_neighbour(rng, 80)
    test, test_attention, test_roles = decided_by_neighbour(rng, 30)
    own = fitted(train, train_roles, RidgeConfig(history_steps=4), train_attention)
    assert own.models[0][0].n_features_in_ == own.own_features == 2 * 4 + 2 * 3
    dropped_config = RidgeConfig(history_steps=4, neighbours="random", neighbour_scales=(0.0,))
    dropped = fitted(train, train_roles, dropped_config, train_attention)
    np.testing.assert_allclose(
        predict(dropped, test, test_roles, test_attention),
        predict(own, test, test_roles, test_attention),
        atol=1e-6,
    )
    banded_config = RidgeConfig(
        history_steps=4, neighbours="labelled", neighbour_scales=BANDED_SCALES
    )
    banded = fitted(train, train_roles, banded_config, train_attention)
    assert banded.models[0].named_steps["functiontransformer"].kw_args["scale"] > 0
    pred = predict(banded, test, test_roles, test_attention)
    assert np.linalg.norm(pred[:, :, 0] - test[:, OBSERVED:, 0, :2], axis=-1).mean() < 0.01
    with pytest.raises(ValueError, match="neighbour_scales must be"):
        RidgeConfig(neighbour_scales=(-1.0,))


def test_incomplete_history_falls_back_to_constant_velocity_and_fitting_is_deterministic():
    rng = np.random.default_rng(3)
    train, test = random_agents(rng, 40, 3, 2.0), random_agents(rng, 10, 3, 2.0)
    roles = np.zeros((40, 3), np.int8)
    valid = np.ones(test.shape[:3], bool)
    valid[:, 2, 1] = False  # agent 1 missed a step early in its history (history_steps=4 ok)
    valid[:, OBSERVED - 3, 2] = False  # agent 2 missed one inside the history window
    first = predict(
        fitted(train, roles, RidgeConfig(history_steps=4)), test, roles[:10], None, valid
    )
    again = predict(
        fitted(train, roles, RidgeConfig(history_steps=4)), test, roles[:10], None, valid
    )
    np.testing.assert_array_equal(first, again)
    cv = constant_velocity(test[..., :2], valid, OBSERVED)
    np.testing.assert_array_equal(first[:, :, 2], cv[:, :, 2])
    assert np.abs(first[:, :, 1] - cv[:, :, 1]).max() > 0.01  # agent 1 still uses the model


def test_refuses_too_short_observations_and_unfitted_use():
    states = random_agents(np.random.default_rng(4), 5, 2, 0.0)
    roles = np.zeros((5, 2), np.int8)
    valid = np.ones(states.shape[:3], bool)
    attention = np.full(states.shape[:3], -1, np.int16)
    with pytest.raises(ValueError, match="fitted"):
        RidgeBaseline().predict(states, valid, attention, roles)
    with pytest.raises(ValueError, match="at least 3 observed steps"):
        RidgeBaseline().fit(states, valid, attention, roles, 2, DT)


def write_gain_file(path, make_split, rng: np.random.Generator):
    """A dataset file whose splits come from `make_split(rng, n)` -> states, attention, roles
    (and optionally the case of each scene)."""
    splits = {}
    for name, n in (("train", 80), ("val", 4), ("test", 30)):
        states, attention, roles, *case = make_split(rng, n)
        shape = states.shape[:3]
        splits[name] = TrajectorySet(
            states=states.astype(np.float32),
            actions=np.zeros((*shape, 2), np.float32),
            valid=np.ones(shape, bool),
            attention=attention,
            interaction=np.ones(shape[:2], bool),
            case=case[0] if case else np.zeros(n, np.int8),
            seed=np.arange(n, dtype=np.int64),
            roles=roles,
        )
    meta = DatasetMeta(
        scenario="decided_by_neighbour",
        dt=DT,
        num_observed=OBSERVED,
        num_predicted=STEPS - OBSERVED,
        case_names=("only", "never"),
        major_case="only",
        role_names=("attending", "attended", "far"),
        config={"made_by": "tests"},
    )
    write_dataset(path, meta, splits)
    return path


def ahead_or_behind(rng: np.random.Generator, n: int):
    """`decided_by_neighbour`, but in case 1 (every other scene) agent 1 drives 6 m behind
    agent 0 instead of 6 m ahead, and agent 0 drifts the other way: the same role reads its
    labelled car with opposite signs by where that car is (as a Double Merge colour, the rear
    car in one case and the front car in the other)."""
    states, attention, roles = decided_by_neighbour(rng, n)
    case = (np.arange(n) % 2).astype(np.int8)
    heading = states[:, 0, 0, 2]
    ahead = np.stack([np.cos(heading), np.sin(heading)], -1)  # (n, 2)
    normal = np.stack([-np.sin(heading), np.cos(heading)], -1)
    t0 = OBSERVED - 1
    lateral = np.einsum("nc,nc->n", states[:, t0, 1, :2] - states[:, t0, 0, :2], normal)
    k = np.arange(1, STEPS - t0)
    drift = 0.05 * lateral[:, None] * k[None] ** 2  # agent 0's drift (decided_by_neighbour)
    rows = case == 1
    states[rows, :, 1, :2] -= 12.0 * ahead[rows, None]
    states[rows, t0 + 1 :, 0, :2] -= 2.0 * drift[rows, :, None] * normal[rows, None]
    return states, attention, roles, case


def decided_by_case(rng: np.random.Generator, n: int):
    """Straight constant-speed histories; after the last observed step agent 0 speeds up along
    its heading in case 0 and slows down in case 1 (every other scene), which its history does
    not show. Agent 1 is its label (uninformative), agents 2-3 drive on."""
    states = random_agents(rng, n, 4, 0.0)
    case = (np.arange(n) % 2).astype(np.int8)
    heading = states[:, 0, 0, 2]
    ahead = np.stack([np.cos(heading), np.sin(heading)], -1)  # (n, 2)
    t0 = OBSERVED - 1
    k = np.arange(1, STEPS - t0)
    sign = np.where(case == 0, 1.0, -1.0)
    states[:, t0 + 1 :, 0, :2] += (0.05 * sign[:, None] * k[None] ** 2)[..., None] * ahead[:, None]
    attention = np.full(states.shape[:3], -1, np.int16)
    attention[:, :, 0] = 1
    roles = np.tile(np.array([0, 1, 2, 2], np.int8), (n, 1))
    return states, attention, roles, case


def test_case_groups_fit_one_regression_per_role_and_case(tmp_path):
    """A future decided by the case alone: one map per role must hedge between speeding up and
    slowing down (its error is the drift itself, closed form 0.05 k^2 m at step k); one map per
    role and case predicts it exactly."""
    rng = np.random.default_rng(7)
    train_states, train_attention, train_roles, train_case = decided_by_case(rng, 60)
    test_states, test_attention, test_roles, test_case = decided_by_case(rng, 20)
    drift = 0.05 * np.arange(1, STEPS - OBSERVED + 1) ** 2
    errors = {}
    for groups in ("role", "case"):
        config = RidgeConfig(history_steps=4, groups=groups)
        model = RidgeBaseline(config).fit(
            train_states, np.ones(train_states.shape[:3], bool), train_attention, train_roles,
            OBSERVED, DT, train_case,
        )  # fmt: skip
        pred = model.predict(
            test_states, np.ones(test_states.shape[:3], bool), test_attention, test_roles, test_case
        )
        errors[groups] = np.linalg.norm(pred[:, :, 0] - test_states[:, OBSERVED:, 0, :2], axis=-1)
    np.testing.assert_allclose(errors["role"].mean(0), drift, rtol=0.05)
    assert errors["case"].max() < 1e-3
    assert set(model.models) == {case * CASE_STRIDE + role for case in (0, 1) for role in (0, 1, 2)}
    with pytest.raises(ValueError, match="needs the case"):
        model.predict(test_states, np.ones(test_states.shape[:3], bool), test_attention, test_roles)

    path = write_gain_file(tmp_path / "case.h5", decided_by_case, np.random.default_rng(8))
    for row in interaction_gain(path, grouping="case"):
        assert row.own < 1e-3 and row.labelled < 1e-3
    done = subprocess.run(
        [
            sys.executable, str(REPO_ROOT / "tools" / "inspect_data.py"), path,
            "--interaction-gain", "--gain-groups", "case",
        ],
        capture_output=True, text=True, env=tool_env(), timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert float(done.stdout.strip().splitlines()[-1].split()[3]) < 1e-3
    alone = subprocess.run(
        [
            sys.executable, str(REPO_ROOT / "tools" / "inspect_data.py"), path,
            "--gain-groups", "case",
        ],
        capture_output=True, text=True, env=tool_env(), timeout=120,
    )  # fmt: skip
    assert alone.returncode == 2
    assert alone.stderr == "error: --gain-groups needs --interaction-gain\n"


def test_interaction_gain_finds_the_deciding_car_and_the_tool_prints_it(tmp_path):
    """Through a dataset file: agent 0's future is decided by agent 1 (its label), so the
    labelled car's history removes nearly all its error and a random car's does not."""
    path = write_gain_file(tmp_path / "gain.h5", decided_by_neighbour, np.random.default_rng(5))

    (row,) = interaction_gain(path)  # only agent 0 has a label, all in case "only"
    assert (row.case, row.role, row.agents) == ("only", "attending", 30)
    assert row.own > 0.3 and row.gain > 0.95 and abs(row.control) < 0.2

    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / "inspect_data.py"), path, "--interaction-gain"],
        capture_output=True,
        text=True,
        env=tool_env(),
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    last = done.stdout.strip().splitlines()[-1].split()
    assert last[:3] == ["only", "attending", "30"]
    assert float(last[3]) == pytest.approx(row.own, abs=5e-4)
    assert float(last[4]) == pytest.approx(row.labelled, abs=5e-4)

    (banded,) = interaction_gain(path, penalty="banded")
    assert banded.own == row.own and banded.gain > 0.95
    (null,) = interaction_gain(path, control="shuffled")  # the label of another scene
    with pytest.raises(ValueError, match="no agent role named distractor"):
        interaction_gain(path, control="distractor")
    assert (null.own, null.labelled) == (row.own, row.labelled) and abs(null.control) < 0.2
    with pytest.raises(ValueError, match="control must be one of"):
        interaction_gain(path, control="psychic")
    with pytest.raises(ValueError, match="penalty must be one of shared, banded"):
        interaction_gain(path, penalty="lasso")
    tool = [sys.executable, str(REPO_ROOT / "tools" / "inspect_data.py"), path]
    done = subprocess.run(
        [*tool, "--interaction-gain", "--gain-penalty", "banded"],
        capture_output=True, text=True, env=tool_env(), timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert float(done.stdout.strip().splitlines()[-1].split()[5]) == pytest.approx(
        banded.random, abs=5e-4
    )
    shuffled = subprocess.run(
        [*tool, "--interaction-gain", "--gain-control", "shuffled"],
        capture_output=True, text=True, env=tool_env(), timeout=120,
    )  # fmt: skip
    assert shuffled.returncode == 0, shuffled.stderr
    header, _, last = shuffled.stdout.strip().splitlines()[-3:]
    assert "+shuffled [m]" in header
    assert float(last.split()[5]) == pytest.approx(null.random, abs=5e-4)
    alone = subprocess.run(
        [*tool, "--gain-penalty", "banded"], capture_output=True, text=True, env=tool_env()
    )
    assert alone.returncode == 2
    assert alone.stderr == "error: --gain-penalty needs --interaction-gain\n"


def test_relation_groups_read_the_labelled_car_ahead_and_behind(tmp_path):
    """One regression per role cannot read a car whose effect flips sign with its place; per
    relation to the labelled car (ahead or behind at the last observed step) it can."""
    path = write_gain_file(tmp_path / "flip.h5", ahead_or_behind, np.random.default_rng(6))
    by_role = {row.case: row for row in interaction_gain(path, grouping="role")}
    by_relation = {row.case: row for row in interaction_gain(path, grouping="relation")}
    assert set(by_role) == set(by_relation) == {"only", "never"}
    for case in ("only", "never"):
        assert by_role[case].own == pytest.approx(by_relation[case].own, rel=0.5)
        assert by_role[case].gain < 0.5  # the two signs cancel in one map
        assert by_relation[case].gain > 0.9 and abs(by_relation[case].control) < 0.2
    with pytest.raises(ValueError, match="groups must be one of"):
        interaction_gain(path, grouping="colour")


def test_relation_groups_by_hand():
    """Agent 0 faces +x with its label ahead, agent 1 faces +x with its label behind, agent 2
    faces -x (heading pi) with its label at larger x, so behind it; agent 3 has no label and
    keeps its role. Without a heading channel the frame is the last displacement's."""
    states = np.zeros((1, 3, 4, 3))  # x, y, heading
    states[0, :, :, 0] = [0.0, 5.0, 10.0, 20.0]
    states[0, :, 2, 2] = np.pi
    attention = np.full((1, 3, 4), -1, np.int16)
    attention[0, :, :3] = [1, 0, 3]
    roles = np.array([[0, 0, 1, 1]], np.int8)
    ahead, behind = RELATION_AHEAD, RELATION_BEHIND
    np.testing.assert_array_equal(
        relation_groups(states, attention, roles, 3), [[ahead, behind, behind, 1]]
    )
    moving = states[..., :2].copy()
    moving[0, :, :, 0] += np.array([0.0, 1.0, 2.0])[:, None] * [1.0, 1.0, -1.0, 1.0]
    np.testing.assert_array_equal(
        relation_groups(moving, attention, roles, 3), [[ahead, behind, behind, 1]]
    )
