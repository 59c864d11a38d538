"""Tests for scenarios.counterfactual.windowed_influence (influence per predicted-time window):
an independent one-scene loop with hand-taken window ADEs, the screen against the exhaustive
method on every registered version, one window over the whole predicted span against the
"predicted" kind, and facts checkable by hand (a removal changes nothing before it acts, so
one-step windows are all zero; the diagonal is 0). Storage is tested in
test_influence_windows_storage.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_influence import tiny_halting_scene

import scenarios
from carlo_lite import BatchedWorld
from scenarios.counterfactual import (
    PREDICTED,
    counterfactual_states,
    influence_matrices,
    window_starts,
    windowed_influence,
)
from scenarios.expert import expert_for


def one_scene_removal(scenario, plan, car: int, remove_at: int) -> tuple[np.ndarray, np.ndarray]:
    """The truth stepped by hand: one scene, `car` (None: nobody) removed before the experts
    read step `remove_at`; positions (T, N, 2) and presence (T, N)."""
    config = scenario.config
    expert = expert_for(scenario, [plan])
    world: BatchedWorld = expert.make_world()
    xy = np.empty((config.num_steps, scenario.num_cars, 2))
    present = np.empty((config.num_steps, scenario.num_cars), dtype=bool)
    for step in range(config.num_steps):
        if step == remove_at and car is not None:
            mask = np.zeros((1, scenario.num_cars), dtype=bool)
            mask[0, car] = True
            world.deactivate(mask)
        expert.update(world)
        xy[step], present[step] = world.xy[0], world.active[0]
        controls = expert.expert_actions(world)
        for _ in range(config.record_every):
            world.step(controls)
    return xy, present


def test_window_starts_cut_the_predicted_steps():
    np.testing.assert_array_equal(window_starts(12, 60, 10), [12, 22, 32, 42, 52])  # last: 8
    np.testing.assert_array_equal(window_starts(12, 60, 48), [12])
    np.testing.assert_array_equal(window_starts(12, 60, 100), [12])
    assert len(window_starts(15, 60, 1)) == 45
    for bad in (0, -3):
        with pytest.raises(ValueError, match="window_steps must be at least 1"):
            window_starts(12, 60, bad)
    for bad in (2.5, True, "4"):
        with pytest.raises(ValueError, match="window_steps must be an integer"):
            window_starts(12, 60, bad)


def test_leader_removal_per_window_matches_a_hand_stepped_loop():
    scenario, plan = tiny_halting_scene()
    config = scenario.config
    window = 10
    influence = windowed_influence(scenario, [plan], window, method="exhaustive")[0]
    starts = range(config.num_observed, config.num_steps, window)
    assert influence.shape == (math.ceil((config.num_steps - config.num_observed) / window), 2, 2)
    factual, _ = one_scene_removal(scenario, plan, None, 0)
    for w, start in enumerate(starts):
        without_leader, present = one_scene_removal(scenario, plan, 1, start)
        assert present[:start, 1].all() and not present[start:, 1].any()
        steps = np.arange(start, min(start + window, config.num_steps))
        expected = np.linalg.norm(factual[steps, 0] - without_leader[steps, 0], axis=1).mean()
        assert expected > 0.1  # braking, then standing: the leader holds the follower back
        assert influence[w, 0, 1] == pytest.approx(expected, rel=1e-5)
        assert influence[w, 1, 0] == 0.0  # the leader's expert never reads the follower
        assert influence[w, 0, 0] == 0.0 and influence[w, 1, 1] == 0.0


def test_a_removal_changes_nothing_before_it_acts():
    scenario = scenarios.make("double_merge_v1")
    plan = scenario.plan(3, "major")
    num_cars, observed = scenario.num_cars, scenario.config.num_observed
    removed = np.zeros((3, num_cars), dtype=bool)
    removed[1:, 1] = True
    at = observed + 20
    states, present = counterfactual_states(scenario, [plan] * 3, removed, [0, at, at])
    # the steps up to the removal, the removal step itself included for the others (recorded
    # before any expert reacts), are the factual rollout's, bit for bit
    np.testing.assert_array_equal(states[1, :at], states[0, :at])
    others = np.arange(num_cars) != 1
    np.testing.assert_array_equal(states[1, at, others], states[0, at, others])
    np.testing.assert_array_equal(present[1, :at], present[0, :at])
    # so one-step windows see no influence at all: 0 where the car is present, else NaN
    ones = windowed_influence(scenario, [plan], 1)
    assert ones.shape == (1, scenario.config.num_steps - observed, num_cars, num_cars)
    assert np.nanmax(ones) == 0.0


def test_one_window_over_the_predicted_span_is_the_predicted_kind():
    scenario = scenarios.make("halting_car_v3")
    plans = [scenario.plan(seed, case) for seed, case in ((0, "stop"), (1, "go"), (2, "stop"))]
    predicted = influence_matrices(scenario, plans)[:, PREDICTED]
    span = scenario.config.num_steps - scenario.config.num_observed
    for window in (span, span + 7):
        windows = windowed_influence(scenario, plans, window)
        assert windows.shape == (3, 1, scenario.num_cars, scenario.num_cars)
        np.testing.assert_array_equal(windows[:, 0], predicted)


@pytest.mark.parametrize("name", scenarios.version_names())
def test_grouped_screen_equals_the_exhaustive_method_per_window(name):
    scenario = scenarios.make(name)
    cases = scenario.case_names
    plans = [scenario.plan(seed, cases[seed % len(cases)]) for seed in range(2)]
    window = 16
    grouped = windowed_influence(scenario, plans, window)
    exhaustive = windowed_influence(scenario, plans, window, method="exhaustive")
    np.testing.assert_array_equal(grouped, exhaustive)
    span = scenario.config.num_steps - scenario.config.num_observed
    assert grouped.shape == (2, math.ceil(span / window), scenario.num_cars, scenario.num_cars)
    assert grouped.dtype == np.float32 and np.isfinite(grouped).all()
    diagonal = np.arange(scenario.num_cars)
    assert (grouped[:, :, diagonal, diagonal] == 0).all()
    assert grouped.max() > 0.1  # somebody reacts to somebody in some window


def test_windowed_influence_is_independent_of_the_batch():
    scenario = scenarios.make("halting_car_v0")
    plans = [scenario.plan(seed, "stop") for seed in range(3)]
    together = windowed_influence(scenario, plans, 12)
    alone = np.concatenate([windowed_influence(scenario, [plan], 12) for plan in plans])
    np.testing.assert_array_equal(together, alone)


def test_bad_arguments_are_refused():
    scenario = scenarios.make("halting_car_v3")
    with pytest.raises(ValueError, match="method must be one of"):
        windowed_influence(scenario, [], 5, method="guess")
    with pytest.raises(ValueError, match="window_steps must be at least 1"):
        windowed_influence(scenario, [], 0)
    assert windowed_influence(scenario, [], 20).shape == (0, 3, 22, 22)
