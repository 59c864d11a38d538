"""scenarios.rollout and rollout_batch: episodes against fingerprints stored from the expert
as it was written per scene (before the per-scene and batched experts became one), a scene's
episode independent of the batch it runs in (sizes, case mixes, unsafe neighbours), forced
actions and plans per scene, and the float trap the expert avoids (`scalar_idm_accel`)."""

from __future__ import annotations

import dataclasses
import json
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from scenarios import (
    VERSIONS,
    DoubleMerge,
    DoubleMergeConfig,
    Episode,
    ReactiveDoubleMerge,
    ReactiveDoubleMergeConfig,
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    rollout,
    rollout_batch,
)
from scenarios.base import Scenario
from scenarios.controllers import IDMParams, idm_accel
from scenarios.expert import scalar_idm_accel

FINGERPRINTS = Path(__file__).parent / "data" / "expert_episodes.json"
SEEDS_PER_CASE = 40
ARRAYS = ("states", "actions", "valid", "attention", "interaction", "roles")
FIELDS = ("collided", "off_road", "seed", "case", "dt", "scenario")


def assert_same_episode(got: Episode, want: Episode) -> None:
    label = f"seed {want.seed} {want.case}"
    for name in ARRAYS:
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape, f"{label}: {name}"
        np.testing.assert_array_equal(a, b, err_msg=f"{label}: {name}")
    for name in FIELDS:
        assert getattr(got, name) == getattr(want, name), f"{label}: {name}"


def fingerprint(episode: Episode) -> dict:
    """What tests/data/expert_episodes.json stores per episode (sums over time, float64)."""
    states, actions = episode.states.astype(np.float64), episode.actions.astype(np.float64)
    return {
        "main_state_sums": states[:, :2].sum(axis=0).ravel().tolist(),
        "main_action_sums": actions[:, :2].sum(axis=0).ravel().tolist(),
        "distractor_state_sums": states[:, 2:].sum(axis=(0, 1)).tolist(),
        "interaction_steps": int(episode.interaction.sum()),
        "attention_sum": int(episode.attention.astype(np.int64).sum()),
    }


@pytest.mark.parametrize("key", sorted(json.loads(FINGERPRINTS.read_text())))
def test_episodes_match_the_fingerprints_of_the_per_scene_expert(key):
    """Stored at commit 69d3810 from the per-scene experts (seeds 0-4 per version and case);
    the published datasets were checked bit for bit when the experts merged, this guards
    against later drift on any machine (a tolerance far below any behavioural change)."""
    name, case = key.split("/")
    scenario = VERSIONS[name].make()
    stored = json.loads(FINGERPRINTS.read_text())[key]
    episodes = rollout_batch(scenario, range(5), [case] * 5)
    for seed, (episode, want) in enumerate(zip(episodes, stored)):
        got = fingerprint(episode)
        for field in ("interaction_steps", "attention_sum"):
            assert got[field] == want[field], (seed, field)
        for field in ("main_state_sums", "main_action_sums", "distractor_state_sums"):
            np.testing.assert_allclose(got[field], want[field], rtol=1e-9, atol=1e-6)


def mixed_slots(scenario: Scenario, num: int, first_seed: int = 0) -> tuple[list, list]:
    """`num` seeds per case, the cases in a fixed random order in one list."""
    seeds = list(range(first_seed, first_seed + 2 * num))
    order = np.random.default_rng(first_seed).permutation(2 * num) % 2
    return seeds, [scenario.case_names[k] for k in order]


@cache
def one_by_one(name: str) -> tuple[Episode, ...]:
    scenario = VERSIONS[name].make()
    seeds, cases = mixed_slots(scenario, SEEDS_PER_CASE)
    return tuple(rollout(scenario, seed, case) for seed, case in zip(seeds, cases))


@pytest.mark.parametrize("name", list(VERSIONS))
def test_a_scene_does_not_depend_on_its_batch(name):
    scenario = VERSIONS[name].make()
    seeds, cases = mixed_slots(scenario, SEEDS_PER_CASE)
    assert {cases.count(case) for case in scenario.case_names} == {SEEDS_PER_CASE}
    want = one_by_one(name)
    # batches of 1, 13, 13, ... and the rest: sizes that do not divide the 80 seeds
    bounds = [0, 1, *range(14, len(seeds), 13), len(seeds)]
    got = []
    for start, end in zip(bounds[:-1], bounds[1:]):
        got += rollout_batch(scenario, seeds[start:end], cases[start:end])
    assert len(got) == len(want)
    for episode, truth in zip(got, want):
        assert_same_episode(episode, truth)


PERTURBED = {  # configs under which some experts collide or leave the road, others do not
    "double_merge_v1 waits on the far side": ReactiveDoubleMerge(
        ReactiveDoubleMergeConfig(wait_offset_m=(-8.0, -0.5))
    ),
    "double_merge_v0 waits on the far side": DoubleMerge(
        DoubleMergeConfig(wait_offset_m=(-8.0, 0.9))
    ),
    "halting_car_v1 short headway": ReactiveHaltingCar(
        ReactiveHaltingCarConfig(time_headway_s=(0.1, 1.0), brake_decel_mps2=(4.0, 8.0))
    ),
}


@pytest.mark.parametrize("label", sorted(PERTURBED))
def test_unsafe_scenes_do_not_disturb_their_neighbours(label):
    scenario = PERTURBED[label]
    seeds, cases = mixed_slots(scenario, 20, first_seed=100)
    want = [rollout(scenario, seed, case) for seed, case in zip(seeds, cases)]
    got = rollout_batch(scenario, seeds, cases)
    unsafe = [e.collided or e.off_road for e in want]
    assert any(unsafe) and not all(unsafe)  # the batch mixes unsafe and safe scenes
    for episode, truth in zip(got, want):
        assert_same_episode(episode, truth)


def test_forced_actions_and_plans_apply_per_scene():
    scenario = VERSIONS["halting_car_v3"].make()
    plans = [scenario.plan(seed, "go") for seed in (4, 5)]
    forced = np.full((2, scenario.config.num_steps, scenario.num_cars, 2), np.nan)
    forced[1, 20:, 1] = (0.0, -5.0)  # scene 1's leader brakes hard from 6 s on
    got = rollout_batch(scenario, [4, 5], ["go", "go"], plans=plans, forced_actions=forced)
    assert_same_episode(got[0], rollout(scenario, 4, "go"))
    assert_same_episode(got[1], rollout(scenario, 5, "go", forced_actions=forced[1]))
    assert got[1].states[-1, 0, 3] < 0.5 < got[0].states[-1, 0, 3]  # the follower stopped


def test_scalar_idm_accel_is_idm_accel_on_scalars():
    """A follower's IDM per scene must equal `idm_accel` on numpy scalars (C `pow`), which is
    what the expert computed when it was written per scene; a free road is an infinite gap."""
    rng = np.random.default_rng(5)
    count = 3000
    speed = rng.uniform(0.0, 15.0, count)
    desired = rng.uniform(8.0, 16.0, count)
    gap = rng.uniform(-1.0, 40.0, count)
    gap[::50] = np.inf
    closing = rng.uniform(-5.0, 5.0, count)
    headway = rng.uniform(1.0, 2.0, count)
    params = IDMParams()
    got = scalar_idm_accel(speed, desired, gap, closing, headway, params)
    want = [
        idm_accel(
            speed[k],
            float(desired[k]),
            gap[k],
            closing[k],
            dataclasses.replace(params, time_headway_s=float(headway[k])),
        )
        for k in range(count)
    ]
    np.testing.assert_array_equal(got, np.array(want))


def test_bad_arguments():
    scenario = ReactiveHaltingCar()
    with pytest.raises(ValueError, match="2 seeds for 1 cases"):
        rollout_batch(scenario, [1, 2], ["go"])
    with pytest.raises(ValueError, match="unknown case"):
        rollout_batch(scenario, [1, 2], ["go", "major"])
    with pytest.raises(ValueError, match="1 plans for 2 seeds"):
        rollout_batch(scenario, [1, 2], ["go", "go"], plans=[scenario.plan(1, "go")])
    with pytest.raises(ValueError, match=r"forced_actions must have shape \(2, 60, 22, 2\)"):
        rollout_batch(scenario, [1, 2], ["go", "go"], forced_actions=np.zeros((60, 22, 2)))
    assert rollout_batch(scenario, [], []) == []
