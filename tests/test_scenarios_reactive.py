"""The reactive scenarios' promises (Double Merge v1, Halting Car v1 to v3): the interaction
starts inside the observed window, each car answers the other after its reaction delay, and
only the attended car's observed history tells what the attending car will do."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scenario_episodes import episodes, plan_of

from scenarios import (
    VERSIONS,
    Episode,
    ReactiveDoubleMerge,
    ReactiveDoubleMergeConfig,
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    rollout,
)
from scenarios.base import BROWN, GREEN


# --- Double Merge v1 ------------------------------------------------------------------------------
def main_order(run: Episode) -> tuple[int, int]:
    """(front, rear): the main car ahead at the start and the other."""
    front = int(np.argmax(run.states[0, :2, 0]))
    return front, 1 - front


@pytest.mark.parametrize("case", ReactiveDoubleMerge.case_names)
def test_double_merge_v1_rear_car_follows_once_it_sees_the_front_car_leave_its_lane(
    case: str,
) -> None:
    """200 seeds: the interaction starts at the first step the front car is 0.2 m out of its
    lane centre, inside the observed window; before the rear car's reaction delay has passed
    after it, the rear car only tracks its cruise (no braking); the swap completes."""
    config = ReactiveDoubleMergeConfig()
    for run in episodes("double_merge_v1", case):
        front, rear = main_order(run)
        assert (front == BROWN) == (case == "major")
        lane, target = run.states[0, front, 1], run.states[0, rear, 1]
        departure = (run.states[:, front, 1] - lane) * np.sign(target - lane)  # (T,)
        seen = int(np.argmax(departure >= config.follow_trigger_m))
        assert np.argmax(run.interaction) == seen <= config.num_observed - 1
        # speed tracking with +-0.3 m/s jitter asks for at most 1.5 x 0.3 m/s^2 of braking
        assert run.actions[: seen + 2, rear, 1].min() > -0.5  # seen + 2: its delay
        assert abs(run.states[-1, front, 1] - target) < 0.05
        assert abs(run.states[-1, rear, 1] - lane) < 0.05


@pytest.mark.parametrize("case", ReactiveDoubleMerge.case_names)
def test_double_merge_v1_front_car_answers_the_rear_car_in_the_predicted_window(
    case: str,
) -> None:
    """200 seeds: at least 80 % of the front car's braking (the sum of its negative
    accelerations) comes after the last observed step, and it does brake; it ends faster than
    the rear car (its margin)."""
    last_observed = ReactiveDoubleMergeConfig().num_observed - 1
    for run in episodes("double_merge_v1", case):
        front, rear = main_order(run)
        braking = np.clip(-run.actions[:, front, 1].astype(float), 0.0, None)  # (T,)
        assert braking[last_observed:].sum() >= 0.8 * braking.sum() > 0.0
        assert run.states[-1, front, 3] > run.states[-1, rear, 3] + 0.5


def test_double_merge_v1_each_main_car_reacts_to_the_other_one_delay_later() -> None:
    """Causal in both directions (forced actions): a rear car forced to brake from step k
    changes the front car's actions from step k + 1 + 4 (0.8 s) on, not earlier; a front car
    forced to brake from step k changes the rear car's from k + 1 + 2 (0.4 s) on; both then
    decelerate more than in the free run."""
    sc = ReactiveDoubleMerge()
    base = rollout(sc, 5, "major")
    front, rear = main_order(base)
    k = 20  # after the front car left its lane: the rear car follows it
    assert base.interaction[k]
    for pushed, reacting, delay in ((rear, front, 4), (front, rear, 2)):
        forced = np.full_like(base.actions, np.nan)
        forced[k:, pushed] = (0.0, -3.0)
        braked = rollout(sc, 5, "major", forced_actions=forced)
        same = k + 1 + delay
        np.testing.assert_array_equal(
            braked.actions[:same, reacting], base.actions[:same, reacting]
        )
        assert not np.array_equal(braked.actions[same, reacting], base.actions[same, reacting])
        later = slice(same, same + 5)  # over the next second it slows down more
        assert (
            braked.actions[later, reacting, 1].sum() < base.actions[later, reacting, 1].sum() - 0.2
        )
    plan = sc.plan(5, "major")
    assert (plan.front_reaction_steps, plan.rear_reaction_steps) == (4, 2)


def test_double_merge_v1_rear_car_brakes_harder_for_a_smaller_gap() -> None:
    """The rear car's braking is set by the gap it observes: the same scene with the front car
    started 3 m closer makes it brake harder (its strongest deceleration)."""
    sc = ReactiveDoubleMerge()
    plan = plan_of("double_merge_v1", 6, "minor")
    state = plan.initial_state.copy()
    state[plan.front, 0] -= 3.0
    closer = dataclasses.replace(plan, initial_state=state)
    base = rollout(sc, 6, "minor", plan=plan)
    near = rollout(sc, 6, "minor", plan=closer)
    assert not near.collided
    assert near.actions[:, plan.rear, 1].min() < base.actions[:, plan.rear, 1].min() - 0.3


# --- Halting Car v1 -------------------------------------------------------------------------------
def test_halting_car_v1_braking_is_observed_and_the_reaction_is_predicted() -> None:
    """Case stop, 200 seeds: the leader brakes for at least two observed steps, the same
    stop-and-go cycle as v0 follows, and at least 80 % of the follower's braking (the sum of
    its negative accelerations) comes after the last observed step."""
    config = ReactiveHaltingCarConfig()
    last_observed = config.num_observed - 1
    for run in episodes("halting_car_v1", "stop"):
        interaction = np.nonzero(run.interaction)[0]
        assert interaction[0] <= last_observed - 2  # onset inside the observed window
        leader_speed = run.states[:, BROWN, 3]
        assert leader_speed[last_observed] < leader_speed[0] - 0.5  # visibly slower by then
        assert abs(leader_speed[-1] - leader_speed[0]) < 0.05  # back at its cruising speed
        braking = np.clip(-run.actions[:, GREEN, 1].astype(float), 0.0, None)  # (T,)
        assert braking[last_observed:].sum() >= 0.8 * braking.sum() > 0.0
        gap = run.states[:, BROWN, 0] - run.states[:, GREEN, 0] - config.car_length_m
        assert gap.min() > 1.0


def test_halting_car_v1_go_case_keeps_speed_and_has_no_interaction() -> None:
    for run in episodes("halting_car_v1", "go"):
        assert not run.interaction.any()
        np.testing.assert_allclose(run.states[:, BROWN, 3], run.states[0, BROWN, 3], atol=1e-5)


def test_halting_car_v1_reaction_delays_are_two_or_three_steps() -> None:
    delays = {plan_of("halting_car_v1", seed, "stop").reaction_steps for seed in range(50)}
    assert delays == {2, 3}  # 0.6 or 0.9 s at 0.3 s per control step


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_halting_car_v1_follower_reacts_to_the_leader_exactly_one_delay_later(seed: int) -> None:
    """Force the leader to brake from step k: its state changes from step k + 1, and the
    follower's actions stay identical up to step k + delay, then change."""
    sc = ReactiveHaltingCar()
    base = rollout(sc, seed, "go")
    delay = sc.plan(seed, "go").reaction_steps
    k = 15
    forced = np.full_like(base.actions, np.nan)
    forced[k:, BROWN] = (0.0, -3.0)
    braked = rollout(sc, seed, "go", forced_actions=forced)
    np.testing.assert_array_equal(braked.states[: k + 1, BROWN], base.states[: k + 1, BROWN])
    np.testing.assert_array_equal(
        braked.actions[: k + 1 + delay, GREEN], base.actions[: k + 1 + delay, GREEN]
    )
    assert braked.actions[k + 1 + delay, GREEN, 1] < base.actions[k + 1 + delay, GREEN, 1]
    assert not braked.collided


# --- Halting Car v2 and v3 ------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["halting_car_v2", "halting_car_v3"])
def test_halting_car_v2_v3_only_the_leader_shows_the_stop_before_prediction(name: str) -> None:
    """200 seeds: the leader's observed states differ between the cases (it brakes for 1-3
    observed steps), the follower's observed states and actions are the same in both (its own
    history cannot tell the case), and it then brakes, with the v1 safety margin."""
    config = VERSIONS[name].config()
    observed = config.num_observed
    for stop, go in zip(episodes(name, "stop"), episodes(name, "go")):
        leader_stop, leader_go = stop.states[:observed, BROWN, 3], go.states[:observed, BROWN, 3]
        slower = np.nonzero(leader_stop < leader_go - 1e-6)[0]
        assert 1 <= len(slower) <= 3 and slower[-1] == observed - 1
        np.testing.assert_array_equal(stop.states[:observed, GREEN], go.states[:observed, GREEN])
        np.testing.assert_array_equal(stop.actions[:observed, GREEN], go.actions[:observed, GREEN])
        assert stop.actions[observed:, GREEN, 1].min() < go.actions[observed:, GREEN, 1].min() - 1
        gap = stop.states[:, BROWN, 0] - stop.states[:, GREEN, 0] - config.car_length_m
        assert gap.min() > 1.0
        assert abs(stop.states[-1, BROWN, 3] - stop.states[0, BROWN, 3]) < 0.05  # resumed


def test_halting_car_v2_plan_is_v1_plan_with_v2_ranges() -> None:
    """Same draws as v1 (the fixed ranges still take theirs): the scene and the cruise agree,
    the brake onset lies in 2.4-3.0 s, the delay is 3 steps, stop and resume are fixed."""
    for seed in range(20):
        v1, v2 = plan_of("halting_car_v1", seed, "stop"), plan_of("halting_car_v2", seed, "stop")
        np.testing.assert_array_equal(v1.initial_state, v2.initial_state)
        assert v1.time_headway_s == v2.time_headway_s
        assert 2.4 <= v2.brake_start_s <= 3.0 and v2.reaction_steps == 3
        assert (v2.stop_duration_s, v2.resume_accel_mps2) == (1.5, 2.5)
    assert isinstance(VERSIONS["halting_car_v2"].make(), ReactiveHaltingCar)


def test_halting_car_v3_last_observed_step_shows_the_same_braking_in_every_stop_scene() -> None:
    """200 seeds: over the last observed step the leader's speed falls by 4 m/s^2 x 0.3 s in
    every `stop` scene and not at all in every `go` scene (the case is one linear reading of
    its history), and its cruise lies in 9-11 m/s."""
    config = VERSIONS["halting_car_v3"].config()
    last = config.num_observed - 1
    drop = config.brake_decel_mps2[0] * config.recorded_dt
    assert config.brake_decel_mps2 == (4.0, 4.0) and drop == pytest.approx(1.2)
    for stop, go in zip(episodes("halting_car_v3", "stop"), episodes("halting_car_v3", "go")):
        assert stop.states[last - 1, BROWN, 3] - stop.states[last, BROWN, 3] == pytest.approx(
            drop, abs=1e-4
        )
        assert go.states[last - 1, BROWN, 3] == go.states[last, BROWN, 3]
        assert 9.0 <= go.states[0, BROWN, 3] <= 11.0


def test_halting_car_v3_plan_is_v2_plan_with_v3_ranges() -> None:
    """Same draws as v2: the onset, the follower's headway and delay, the stop and resume
    agree; the cruise lies in 9-11 m/s and the deceleration is 4 m/s^2."""
    for seed in range(20):
        v2, v3 = plan_of("halting_car_v2", seed, "stop"), plan_of("halting_car_v3", seed, "stop")
        assert (v2.brake_start_s, v2.time_headway_s) == (v3.brake_start_s, v3.time_headway_s)
        assert v2.reaction_steps == v3.reaction_steps
        assert (v2.stop_duration_s, v2.resume_accel_mps2) == (
            v3.stop_duration_s,
            v3.resume_accel_mps2,
        )
        assert 9.0 <= v3.cruise_speed_mps <= 11.0 and v3.brake_decel_mps2 == 4.0
    assert isinstance(VERSIONS["halting_car_v3"].make(), ReactiveHaltingCar)
