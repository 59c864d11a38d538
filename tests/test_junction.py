"""Junction scenarios (scenarios.junction, left_turn, roundabout_entry) and the worlds on road
layouts they drive in: closed forms of the shared pieces, then each family's behaviour over the
200 seeds per case of the scenario tests (scenario_episodes), its causal labels and its
counterfactual influence. Safety, determinism and the recorded arrays are checked for every
version in test_scenarios.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scenario_episodes import JUNCTION_CASES, episodes, scenario

from carlo_lite import BatchedWorld, Intersection, LanePath, World, render_rgb
from scenarios import rollout, rollout_batch
from scenarios.counterfactual import influence_matrices
from scenarios.junction import conflict_point, profile_speed, time_to_cover
from scenarios.left_turn import LeftTurn
from scenarios.roundabout_entry import RoundaboutEntry

DISTRACTOR = 2  # role index


# --- geometry and the world on a layout ---------------------------------------------------------
def test_lane_curvature_is_signed_inverse_radius_on_arcs_and_zero_elsewhere() -> None:
    lane = LanePath((0.0, 0.0), 0.0).straight(10.0).turn(8.0, np.pi / 2).turn(5.0, -0.5).lane()
    s = np.array([-1.0, 5.0, 12.0, 10.0 + 4.0 * np.pi + 1.0, lane.length_m + 2.0])
    np.testing.assert_allclose(lane.curvature_at(s), [0.0, 0.0, 1 / 8, -1 / 5, 0.0])


def test_a_car_is_off_a_layout_when_its_centre_leaves_every_lane() -> None:
    layout = Intersection(arm_length_m=30.0).layout
    lane = layout.lanes["in_south"]  # x = +1.75, heading north, from y = -37.5 to -7.5
    state = np.array(
        [
            [1.75, -20.0, np.pi / 2, 5.0],  # on its lane's centre
            [3.4, -30.0, np.pi / 2, 5.0],  # half its body past the lane's edge at x = 3.5
            [3.6, -40.0, np.pi / 2, 5.0],  # its centre 0.1 m past that edge
            [20.0, -20.0, 0.0, 5.0],  # on the grass between two arms
        ]
    )
    assert lane.contains(state[0, :2]) and not lane.contains(np.array([3.6, -20.0]))
    world = BatchedWorld(layout, state[None])
    collided, off_road = world.incidents()
    assert off_road[0].tolist() == [False, False, True, True]
    assert not collided.any()
    frame = render_rgb(World.of(world), 200, 200)  # the layout fitted in a square frame
    assert frame.shape == (200, 200, 3) and len(np.unique(frame.reshape(-1, 3), axis=0)) >= 3


def test_profile_speed_follows_its_phases() -> None:
    # cruise 10, brake at 2 s at 2 m/s^2 to 4 (reached at 5 s), hold 1 s, resume at 1 m/s^2
    times = np.array([0.0, 2.0, 3.5, 5.0, 5.5, 6.0, 8.0, 20.0])
    speed = profile_speed(times, *(np.full(8, v) for v in (10.0, 2.0, 2.0, 4.0, 1.0, 1.0)))
    np.testing.assert_allclose(speed, [10.0, 10.0, 7.0, 4.0, 4.0, 4.0, 6.0, 10.0])
    waiting = profile_speed(np.array([100.0]), *(np.array([v]) for v in (8, 1, 4, 0, np.inf, 1)))
    assert waiting.tolist() == [0.0]


def test_time_to_cover_matches_constant_acceleration_then_top_speed() -> None:
    # from 2 m/s at 2 m/s^2 up to 6 m/s: 2 s and 8 m of ramp, then 6 m/s
    got = time_to_cover(
        np.array([0.0, 3.0, 8.0, 20.0, -1.0]), np.full(5, 2.0), 2.0, np.full(5, 6.0)
    )
    np.testing.assert_allclose(got, [0.0, 1.0, 2.0, 4.0, 0.0])


def test_conflict_point_of_two_crossing_lanes() -> None:
    east = LanePath((0.0, 0.0), 0.0).straight(40.0).lane()
    north = LanePath((25.0, -10.0), np.pi / 2).straight(30.0).lane()
    assert conflict_point(east, north) == pytest.approx((25.0, 10.0), abs=0.05)
    with pytest.raises(ValueError, match="do not cross"):
        conflict_point(east, LanePath((0.0, 5.0), 0.0).straight(40.0).lane())


# --- every junction family -----------------------------------------------------------------------
@pytest.mark.parametrize(("name", "case"), JUNCTION_CASES)
def test_cars_follow_their_routes_and_distractor_columns_brake_without_closing_up(
    name: str, case: str
) -> None:
    sc = scenario(name)
    runs = episodes(name, case)
    distractors = np.nonzero(sc.roles == DISTRACTOR)[0]
    size = sc.config.platoon_size
    braked = 0
    for run in runs[:50]:
        plan = sc.plan(run.seed, case)
        for car in range(sc.num_cars):  # within 0.7 m of the route's centre-line all episode
            _, d = sc.routes[plan.route[car]].local_coordinates(
                run.states[:, car, :2].astype(float)
            )
            assert np.abs(d).max() < 0.7
        speed = run.states[:, distractors, 3]
        braked += (speed.min(axis=0) < 0.7 * speed[0]).any()
        for column in distractors.reshape(-1, size):  # gaps inside a column never change
            xy = run.states[:, column, :2]
            gaps = np.linalg.norm(np.diff(xy, axis=1), axis=-1)  # (T, size - 1)
            np.testing.assert_allclose(gaps, gaps[:1].repeat(len(gaps), 0), atol=0.05)
    assert braked == 50  # in every scene some distractor column brakes


@pytest.mark.parametrize(("name", "case"), JUNCTION_CASES)
def test_batched_scenes_match_scenes_rolled_out_alone(name: str, case: str) -> None:
    sc = scenario(name)
    batch = rollout_batch(sc, [3, 4, 5], [case] * 3)
    for run in batch:
        alone = rollout(sc, run.seed, case)
        for field in ("states", "actions", "attention", "interaction"):
            np.testing.assert_array_equal(getattr(run, field), getattr(alone, field))


@pytest.mark.parametrize(("name", "case"), JUNCTION_CASES)
def test_influence_of_labelled_cars_and_distractors(name: str, case: str) -> None:
    """Counterfactual ground truth: a distractor moves no main car at all; a car that the label
    names moves the attending car's predicted steps, removed for the whole episode or from the
    first predicted step, except the circulating car that the entering car reads and then goes
    ahead of (roundabout `go`): it would have gone without it, so that label has no influence."""
    sc = scenario(name)
    distractors = sc.roles == DISTRACTOR
    plans = [sc.plan(seed, case) for seed in range(20)]
    influence = influence_matrices(sc, plans)  # (B, 2, N, N)
    for run, matrix in zip(episodes(name, case)[:20], influence):
        assert matrix[:, :, distractors][:, ~distractors].max() == 0.0
        for agent in np.nonzero((run.attention >= 0).any(axis=0))[0]:
            named = np.unique(run.attention[:, agent][run.attention[:, agent] >= 0])
            reads_only = name.startswith("roundabout") and case == "go" and agent == 0
            if reads_only:
                assert matrix[:, agent, named].max() == 0.0
            else:
                assert (matrix[:, agent, named].max(axis=-1) > 0.05).all()


# --- Unprotected Left Turn -----------------------------------------------------------------------
def _route_s(sc, route: int, xy: np.ndarray) -> np.ndarray:
    return sc.routes[route].local_coordinates(xy.astype(float))[0]


@pytest.mark.parametrize("case", LeftTurn.case_names)
def test_left_turn_waits_for_the_cars_its_case_says_and_attention_moves_along_the_stream(
    case: str,
) -> None:
    sc = scenario("left_turn_v0")
    clear = sc.config.conflict_clear_m
    for run in episodes("left_turn_v0", case):
        labels = run.attention[:, 0]
        read = [int(car) for car, _ in _runs(labels) if car >= 0]
        # one oncoming car after the other, in stream order, each for a contiguous span
        assert read == sorted(read) and read[0] == 1
        assert len(read) == (2 if case == "first_gap" else 3)
        # the turning car enters the crossing only once every car it waited for has left it
        turn_s = _route_s(sc, 0, run.states[:, 0, :2])
        inside = turn_s + 2.25 >= sc.turn_conflict_s - clear
        enters = np.argmax(inside) if inside.any() else len(inside)  # still waiting at the end
        for car in read[:-1]:
            car_s = _route_s(sc, 1, run.states[:, car, :2])
            left = np.argmax(car_s - 2.25 > sc.oncoming_conflict_s + clear)
            assert car_s[-1] - 2.25 > sc.oncoming_conflict_s + clear and left <= enters
        assert (run.attention[:, 1:] == -1).all()  # the others attend to nobody


def test_left_turn_car_waits_longer_for_an_oncoming_car_forced_to_slow() -> None:
    """The turning car's label is causal: the oncoming car it waits for, forced to slow down
    after the observed steps, keeps it at its line longer; nobody collides."""
    sc = LeftTurn()
    base = rollout(sc, 2, "first_gap")
    forced = np.full_like(base.actions, np.nan)
    forced[12:18, 1] = (0.0, -1.5)  # the first oncoming car slows by 2.7 m/s, then cruises
    slowed = rollout(sc, 2, "first_gap", forced_actions=forced)
    assert not slowed.collided

    def goes(run):  # the step at which it stops reading the stream
        return np.flatnonzero(run.attention[:, 0] >= 0)[-1]

    assert goes(slowed) > goes(base)
    np.testing.assert_array_equal(slowed.states[:13, 0], base.states[:13, 0])
    assert np.abs(slowed.states[:, 0, :2] - base.states[:, 0, :2]).max() > 1.0


def _runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """(value, length) of the runs of equal consecutive values."""
    edges = np.flatnonzero(np.diff(labels)) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(labels)]])
    return [(int(labels[a]), int(b - a)) for a, b in zip(starts, ends)]


# --- Roundabout Entry ----------------------------------------------------------------------------
ROUNDABOUTS = sorted({name for name, _ in JUNCTION_CASES if name.startswith("roundabout_entry")})


@pytest.mark.parametrize("case", RoundaboutEntry.case_names)
@pytest.mark.parametrize("name", ROUNDABOUTS)
def test_roundabout_entering_car_yields_or_goes_as_its_case_says(name: str, case: str) -> None:
    sc = scenario(name)
    brown_followed = 0
    for run in episodes(name, case):
        plan = sc.plan(run.seed, case)
        green_s = _route_s(sc, plan.route[0], run.states[:, 0, :2])
        brown_s = _route_s(sc, plan.route[1], run.states[:, 1, :2])
        green_in = np.argmax(green_s >= sc.green_merge_s)  # green joins the ring
        brown_past = np.argmax(brown_s >= sc.brown_merge_s[0])  # brown passes green's entry
        assert green_s[-1] >= sc.green_merge_s and brown_s[-1] >= sc.brown_merge_s[0]
        assert (green_in > brown_past) == (case == "yield")
        assert run.attention[0, 0] == 1  # green reads brown from the start
        brown_followed += (run.attention[:, 1] == 0).any()
    # in `go` brown closes up behind green and follows it; in `yield` it never attends to it
    assert brown_followed >= (190 if case == "go" else 0)
    assert brown_followed == 0 or case == "go"


def test_roundabout_v1_green_decides_after_the_observed_window_when_its_approach_says() -> None:
    """v1 times the circulating car from the entering car's decision, which `sample_plan`
    finds by stepping its approach: in every `go` scene the car commits (stops reading the
    circulating car) at that control step or the next, and never inside the observed window."""
    sc = scenario("roundabout_entry_v1")
    period = sc.control_period_s
    for run in episodes("roundabout_entry_v1", "go"):
        plan = sc.plan(run.seed, "go")
        route = sc.routes[plan.route[0]]
        centre_s = float(route.local_coordinates(plan.initial_state[0, :2])[0])
        _, _, decided_at = sc.approach_to_decision(centre_s, plan.approach_speed_mps)
        committed = int(np.argmax(run.attention[:, 0] != 1))  # the first step it reads no one
        assert committed >= sc.config.num_observed
        assert 0 <= committed - round(decided_at / period) <= 1


def test_roundabout_green_waits_longer_for_a_slower_circulating_car() -> None:
    """Causal label: the same scene with the brown car slower keeps green at its line longer."""
    sc = RoundaboutEntry()
    plan = sc.plan(7, "yield")
    state = plan.initial_state.copy()
    state[1, 3] *= 0.8
    slower = dataclasses.replace(
        plan, initial_state=state, circulating_speed_mps=plan.circulating_speed_mps * 0.8
    )
    base, changed = rollout(sc, 7, "yield", plan=plan), rollout(sc, 7, "yield", plan=slower)
    entry = sc.yield_line_s

    def crossing(run):
        return np.argmax(_route_s(sc, plan.route[0], run.states[:, 0, :2]) > entry)

    assert crossing(changed) > crossing(base)
