"""Tests for scenarios.counterfactual (influence matrices) and their storage (schema 4): a
hand-built scene with a closed-form counterfactual, the screen against the exhaustive method,
an independent one-scene loop for the "from the first predicted step" kind, determinism, and
the file round trip, old schemas and validation."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import make_meta, make_trajectory_set

import scenarios
from carlo_lite import BatchedWorld
from pipeline.generation import GenerateConfig, generate_dataset
from scenarios.counterfactual import (
    EPISODE,
    PREDICTED,
    counterfactual_states,
    influence_matrices,
    screening_groups,
)
from scenarios.expert import expert_for
from scenarios.halting_car import HaltingCarConfig, HaltingCarPlan
from scenarios.rollout import rollout
from trajectory_data.format import INFLUENCE, FormatError, write_dataset
from trajectory_data.reader import influence_rows, read_dataset, read_meta


def tiny_halting_scene() -> tuple[scenarios.Scenario, HaltingCarPlan]:
    """Halting Car v0 with no distractors: a leader (car 1) 30 m ahead of a follower (car 0),
    both at 10 m/s, the follower's desired speed 10 m/s (so without a leader its IDM
    acceleration is exactly 0); the leader brakes at 4 m/s^2 from 4 s on (after the 3.6 s
    observed) and stands still for the rest of the episode."""
    version = scenarios.version("halting_car_v0")
    scenario = version.make(HaltingCarConfig(num_distractors=0))
    y = scenario.road.lane_center_y(1)
    plan = HaltingCarPlan(
        initial_state=np.array([[50.0, y, 0.0, 10.0], [84.5, y, 0.0, 10.0]]),
        lane_y=np.array([y, y]),
        target_speed=np.array([10.0, 10.0]),
        cruise_speed_mps=10.0,
        follower_desired_speed_mps=10.0,
        time_headway_s=1.2,
        brake_start_s=4.0,
        brake_decel_mps2=4.0,
        stop_duration_s=100.0,
        resume_accel_mps2=2.0,
        stops=True,
    )
    return scenario, plan


def test_removing_the_leader_gives_the_closed_form_free_road_follower():
    scenario, plan = tiny_halting_scene()
    config = scenario.config
    factual = rollout(scenario, 0, "stop", plan=plan).states.astype(np.float64)  # (T, 2, 4)
    influence = influence_matrices(scenario, [plan], method="exhaustive")[0]
    # without the leader the follower keeps 10 m/s exactly: x(t) = 50 + 10 t, t = 0.3 s a step
    steps = np.arange(config.num_observed, config.num_steps)
    free = 50.0 + 10.0 * config.recorded_dt * steps
    expected = np.abs(factual[steps, 0, 0] - free).mean()
    assert expected > 5.0  # the leader's stop matters a lot
    assert influence[EPISODE, 0, 1] == pytest.approx(expected, rel=1e-5)
    # the leader's expert never reads the follower; the diagonal is 0
    assert influence[EPISODE, 1, 0] == 0.0 and influence[PREDICTED, 1, 0] == 0.0
    assert (np.diagonal(influence, axis1=1, axis2=2) == 0).all()
    # removed from the first predicted step, the follower has seen the leader (slowed a little
    # behind it) and then also drives free: less displacement, still large
    assert 0 < influence[PREDICTED, 0, 1] < influence[EPISODE, 0, 1]


def one_scene_predicted_removal(scenario, plan, car: int) -> np.ndarray:
    """The follower-independent truth of kind `predicted`: one scene, stepped by hand, car
    removed before the experts read step num_observed; positions (T, N, 2)."""
    config = scenario.config
    expert = expert_for(scenario, [plan])
    world: BatchedWorld = expert.make_world()
    out = np.empty((config.num_steps, scenario.num_cars, 2))
    for step in range(config.num_steps):
        if step == config.num_observed:
            mask = np.zeros((1, scenario.num_cars), dtype=bool)
            mask[0, car] = True
            world.deactivate(mask)
        expert.update(world)
        out[step] = world.xy[0]
        controls = expert.expert_actions(world)
        for _ in range(config.record_every):
            world.step(controls)
    return out


def test_predicted_kind_matches_a_one_scene_loop_and_keeps_the_observed_steps():
    scenario = scenarios.make("double_merge_v1")
    plan = scenario.plan(3, "major")
    removed = np.zeros((2, scenario.num_cars), dtype=bool)
    removed[:, 1] = True
    states, present = counterfactual_states(scenario, [plan, plan], removed, [0, 15])
    truth = one_scene_predicted_removal(scenario, plan, 1)
    np.testing.assert_array_equal(states[1, :, :, :2], truth)
    factual = rollout(scenario, 3, "major").states
    observed = scenario.config.num_observed
    np.testing.assert_array_equal(states[1, :observed].astype(np.float32), factual[:observed])
    assert not present[1, observed:, 1].any() and present[1, :observed, 1].all()
    assert not present[0, :, 1].any()


def test_screening_groups_separate_every_ordered_pair():
    for num_cars in (2, 3, 22, 33):
        groups = screening_groups(num_cars)
        separated = groups[:, None, :] & ~groups[:, :, None]  # [g, i, j]: j in g, i not
        off_diagonal = ~np.eye(num_cars, dtype=bool)
        assert (separated.any(axis=0) == off_diagonal).all()


@pytest.mark.parametrize("name", scenarios.version_names())
def test_grouped_screen_equals_the_exhaustive_method(name):
    scenario = scenarios.make(name)
    cases = scenario.case_names
    plans = [scenario.plan(seed, cases[seed % len(cases)]) for seed in range(2)]
    grouped = influence_matrices(scenario, plans)
    exhaustive = influence_matrices(scenario, plans, method="exhaustive")
    np.testing.assert_array_equal(grouped, exhaustive)
    assert grouped.shape == (2, 2, scenario.num_cars, scenario.num_cars)
    assert grouped.dtype == np.float32 and np.isfinite(grouped).all()


def test_influence_is_deterministic_and_independent_of_the_batch():
    scenario = scenarios.make("halting_car_v3")
    plans = [scenario.plan(seed, "stop") for seed in range(3)]
    together = influence_matrices(scenario, plans)
    alone = np.concatenate([influence_matrices(scenario, [plan]) for plan in plans])
    np.testing.assert_array_equal(together, alone)
    np.testing.assert_array_equal(together, influence_matrices(scenario, plans))


def test_bad_arguments_are_refused():
    scenario = scenarios.make("halting_car_v3")
    with pytest.raises(ValueError, match="method must be one of"):
        influence_matrices(scenario, [], method="guess")
    assert influence_matrices(scenario, []).shape == (0, 2, 22, 22)
    with pytest.raises(ValueError, match="removed must be"):
        counterfactual_states(scenario, [scenario.plan(0, "stop")], np.zeros((1, 3)), [0])


# ---- storage --------------------------------------------------------------------------------
def test_generated_influence_round_trips_and_labels_lead(tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v3", num_major=4, num_minor=1, num_test=2)
    plain = generate_dataset(config, tmp_path / "plain.h5", progress=False)
    result = generate_dataset(config, tmp_path / "inf.h5", progress=False, influence=True)
    meta, splits = read_dataset(result.path)
    assert meta.schema_version == 4 and meta.has(INFLUENCE)
    assert read_meta(plain.path).schema_version == 2
    _, plain_splits = read_dataset(plain.path)
    scenario = scenarios.make("halting_car_v3")
    for name, data in splits.items():
        assert plain_splits[name].influence is None
        np.testing.assert_array_equal(data.states, plain_splits[name].states)
        plans = [scenario.plan(int(s), meta.case_names[c]) for s, c in zip(data.seed, data.case)]
        np.testing.assert_array_equal(data.influence, influence_matrices(scenario, plans))
    rows = influence_rows(meta, splits)
    assert {row["role"] for row in rows} == {"main_green"}
    assert all(row["share_above"] == 1.0 for row in rows)
    with pytest.raises(ValueError, match="single files only"):
        generate_dataset(config, tmp_path / "shards", progress=False, influence=True, shard_size=3)


def small_influence_set(n: int = 3, agents: int = 4, seed: int = 1):
    data = make_trajectory_set(n, 10, agents, seed=seed)
    rng = np.random.default_rng(seed)
    influence = rng.uniform(0, 5, (n, 2, agents, agents)).astype(np.float32)
    return dataclasses.replace(data, influence=influence)


def test_influence_file_round_trip_subset_concatenate_and_padding(tmp_path):
    meta = dataclasses.replace(make_meta(), recorded=(*make_meta().recorded, INFLUENCE))
    splits = {"train": small_influence_set(3), "test": small_influence_set(2, seed=2)}
    path = write_dataset(tmp_path / "inf.h5", meta, splits)
    read_back_meta, read_back = read_dataset(path)
    assert read_back_meta.schema_version == 4
    np.testing.assert_array_equal(read_back["train"].influence, splits["train"].influence)
    assert read_back["val"].influence.shape == (0, 2, 4, 4)
    np.testing.assert_array_equal(
        read_back["train"].subset([2, 0]).influence, splits["train"].influence[[2, 0]]
    )
    wide = small_influence_set(1, agents=5, seed=3)
    joined = type(wide).concatenate([splits["train"], wide])
    assert joined.influence.shape == (4, 2, 5, 5)
    assert (
        np.isnan(joined.influence[:3, :, 4]).all() and np.isnan(joined.influence[:3, :, :, 4]).all()
    )
    np.testing.assert_array_equal(joined.influence[3], wide.influence[0])
    mixed = type(wide).concatenate([splits["train"], make_trajectory_set(1, 10, 4)])
    assert mixed.influence is None


def test_older_schema_files_read_without_influence(tmp_path):
    meta = make_meta()
    path = write_dataset(tmp_path / "old.h5", meta, {"train": make_trajectory_set(2, 10, 4)})
    with h5py.File(path) as file:
        assert file.attrs["schema_version"] == 2 and "influence" not in file["train"]
    read_meta_, splits = read_dataset(path)
    assert not read_meta_.has(INFLUENCE) and splits["train"].influence is None


def test_influence_shape_dtype_and_listing_are_validated_on_load(tmp_path):
    meta = dataclasses.replace(make_meta(), recorded=(*make_meta().recorded, INFLUENCE))
    path = write_dataset(tmp_path / "inf.h5", meta, {"train": small_influence_set(3)})
    bad = tmp_path / "bad.h5"
    bad.write_bytes(path.read_bytes())
    with h5py.File(bad, "r+") as file:
        del file["train/influence"]
        file["train"].create_dataset("influence", data=np.zeros((3, 2, 4, 3), np.float32))
    with pytest.raises(FormatError, match=r"influence has shape \(3, 2, 4, 3\), expected"):
        read_dataset(bad)
    with h5py.File(bad, "r+") as file:
        del file["train/influence"]
    with pytest.raises(FormatError, match="missing dataset 'influence'"):
        read_dataset(bad)
    with h5py.File(bad, "r+") as file:
        file["train"].create_dataset("influence", data=np.zeros((3, 2, 4, 4), np.float64))
    with pytest.raises(FormatError, match="influence is float64"):
        read_dataset(bad)
    unlisted = tmp_path / "unlisted.h5"
    write_dataset(unlisted, make_meta(), {"train": make_trajectory_set(3, 10, 4)})
    with h5py.File(unlisted, "r+") as file:
        file["train"].create_dataset("influence", data=np.zeros((3, 2, 4, 4), np.float32))
    with pytest.raises(FormatError, match="leaves out"):
        read_dataset(unlisted)
    with pytest.raises(FormatError, match="holds it"):
        write_dataset(tmp_path / "x.h5", make_meta(), {"train": small_influence_set(3)})
    negative = small_influence_set(3)
    negative.influence[0, 0, 0, 1] = -1.0
    with pytest.raises(FormatError, match="non-negative"):
        write_dataset(tmp_path / "y.h5", meta, {"train": negative})


def test_file_without_influence_keeps_the_schema_2_bytes(tmp_path: Path):
    """The writer writes schema 2 where no influence is recorded: the same bytes whatever the
    package knows about schema 4 (the header differs in nothing but what it must)."""
    meta = make_meta()
    path = write_dataset(tmp_path / "a.h5", meta, {"train": make_trajectory_set(2, 10, 4)})
    with h5py.File(path) as file:
        assert int(file.attrs["schema_version"]) == 2
        assert "influence" not in file.attrs["recorded"]
