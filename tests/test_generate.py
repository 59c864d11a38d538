"""Dataset generation: pipeline.generation (config validation, counts, determinism across runs
and workers, atomicity, refusing to overwrite, interrupts) and tools/generate.py's arguments.
The command line is in test_generate_cli.py, sharded output in test_generate_sharded.py."""

from __future__ import annotations

import dataclasses
import os
import signal
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import load_tool

from pipeline import episode_runner, generation
from pipeline.generation import GenerateConfig, default_output, generate_dataset, plan
from scenarios import VERSIONS, rollout_batch
from scenarios.rollout import rollout
from trajectory_data.format import OPTIONAL_FIELDS
from trajectory_data.reader import read_dataset, read_meta

generate_tool = load_tool("generate.py")

SMALL = dict(num_major=5, num_minor=2, num_test=3)  # 4 + 1 major, 2 + 0 minor, 3 + 3 test


def counts(config: GenerateConfig) -> dict[tuple[str, str], int]:
    tally: dict[tuple[str, str], int] = {}
    for slot in plan(config):
        tally[(slot.split, slot.case)] = tally.get((slot.split, slot.case), 0) + 1
    return tally


# ---- config ------------------------------------------------------------------------------------
def test_default_counts_follow_the_paper():
    config = GenerateConfig.for_scenario("double_merge_v0", minor_ratio=0.3)
    assert (config.major_case, config.minor_case) == ("major", "minor")
    assert counts(config) == {
        ("train", "major"): 40,
        ("val", "major"): 10,
        ("train", "minor"): 12,
        ("val", "minor"): 3,
        ("test", "major"): 50,
        ("test", "minor"): 50,
    }
    assert GenerateConfig.for_scenario("double_merge_v0") == config  # 0.3 is the default ratio


@pytest.mark.parametrize(
    "kwargs, minor_pool, major_pool",
    [
        (dict(minor_ratio=0.8), 40, 50),
        (dict(num_major=10, num_minor=3), 3, 10),
        (dict(num_major=30, num_minor=15), 15, 30),
        (dict(num_major=100, num_minor=30), 30, 100),
        (dict(num_major=100, minor_ratio=0.3), 30, 100),
    ],
)
def test_paper_settings_counts(kwargs, minor_pool, major_pool):
    config = GenerateConfig.for_scenario("halting_car_v0", **kwargs)
    assert (config.major_case, config.minor_case) == ("stop", "go")
    tally = counts(config)
    assert tally[("train", "go")] + tally[("val", "go")] == minor_pool
    assert tally[("train", "stop")] + tally[("val", "stop")] == major_pool
    assert tally[("val", "stop")] == round(0.2 * major_pool)
    seeds = [slot.seed for slot in plan(config)]
    assert seeds == [generation.SEED_STRIDE * config.seed + k for k in range(len(seeds))]


def test_default_scenario_is_double_merge_v1_and_v0_stays_available():
    config = GenerateConfig.for_scenario()
    assert (config.scenario, config.major_case, config.minor_case) == (
        "double_merge_v1",
        "major",
        "minor",
    )
    assert generate_tool.config_from_args(generate_tool.parse_args([])) == config
    args = generate_tool.parse_args(["--scenario", "double_merge_v0"])
    assert generate_tool.config_from_args(args).scenario == "double_merge_v0"


def test_go_as_major_case_and_cli_builds_the_same_config():
    config = GenerateConfig.for_scenario("halting_car_v0", major_case="go", num_major=7, seed=2)
    assert (config.major_case, config.minor_case, config.num_minor) == ("go", "stop", 2)
    args = generate_tool.parse_args(
        ["--scenario", "halting_car_v0", "--major-case", "go", "--num-major", "7", "--seed", "2"]
    )
    assert generate_tool.config_from_args(args) == config
    assert default_output(config) == Path("data/halting_car_v0_go-major_7+2_seed2.h5")


VALID = dict(scenario="halting_car_v0", major_case="stop", minor_case="go")


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(scenario="hovercraft"), "scenario"),
        (dict(major_case="major"), "major_case"),
        (dict(minor_case="left"), "minor_case"),
        (dict(minor_case="stop"), "minor_case"),
        (dict(num_major=0), "num_major"),
        (dict(num_major=2.5), "num_major"),
        (dict(num_major=True), "num_major"),
        (dict(num_minor=-1), "num_minor"),
        (dict(num_test=-1), "num_test"),
        (dict(val_fraction=1.0), "val_fraction"),
        (dict(val_fraction=-0.1), "val_fraction"),
        (dict(val_fraction=float("nan")), "val_fraction"),
        (dict(val_fraction="0.2"), "val_fraction"),
        (dict(seed=-1), "seed"),
    ],
)
def test_config_rejects_bad_fields_in_one_line_naming_the_field(changes, field):
    with pytest.raises(ValueError) as error:
        GenerateConfig(**{**VALID, **changes})
    message = str(error.value)
    assert field in message and "\n" not in message
    if "scenario" not in changes:
        assert message.startswith(field)


def test_config_accepts_the_edges_of_its_ranges():
    config = GenerateConfig(**VALID, num_major=1, num_minor=0, num_test=0, val_fraction=0.0)
    assert counts(config) == {("train", "stop"): 1}


@pytest.mark.parametrize(
    "kwargs, text",
    [
        (dict(minor_ratio=0.3, num_minor=3), "either minor_ratio or num_minor"),
        (dict(minor_ratio=-0.1), "minor_ratio"),
        (dict(minor_ratio=1e6), "minor_ratio"),
        (dict(minor_ratio=1.5), r"minor_ratio must be in \[0, 1\] \(the minor case is the rarer"),
        (dict(num_major=4, num_minor=5), r"num_minor \(5\) must be at most num_major \(4\)"),
        (dict(minor_ratio=float("nan")), "minor_ratio"),
        (dict(major_case="major"), "major_case"),
        (dict(num_major=0), "num_major"),
    ],
)
def test_for_scenario_rejects_bad_values(kwargs, text):
    with pytest.raises(ValueError, match=text):
        GenerateConfig.for_scenario("halting_car_v0", **kwargs)


# ---- generate_dataset --------------------------------------------------------------------------
def test_round_trip_file_contents(tmp_path):
    out = tmp_path / "sub" / "hc.h5"  # missing directories are created
    config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)
    result = generate_dataset(config, out, progress=False)
    assert result.path == out and result.rejected == 0 and result.num_agents == 22
    assert result.counts == {
        "train": {"stop": 4, "go": 2},
        "val": {"stop": 1, "go": 0},
        "test": {"stop": 3, "go": 3},
    }
    assert result.summary().startswith(f"wrote {out}: train 4 stop + 2 go; val 1 stop + 0 go;")
    meta, splits = read_dataset(out)
    assert meta == result.meta
    assert meta.scenario == "halting_car_v0" and meta.major_case == "stop"
    assert meta.config["generator"] == dataclasses.asdict(config)
    assert splits["train"].n == 4 + 2 and splits["val"].n == 1 + 0 and splits["test"].n == 6
    case_names = list(meta.case_names)
    test_cases = [case_names[i] for i in splits["test"].case]
    assert test_cases == ["stop"] * 3 + ["go"] * 3
    # the stored arrays are exactly what the scenario's rollout gives for the stored seeds
    scenario = VERSIONS["halting_car_v0"].make()
    index = 4
    episode = rollout(scenario, int(splits["test"].seed[index]), test_cases[index])
    np.testing.assert_array_equal(splits["test"].states[index], episode.states.astype(np.float32))
    np.testing.assert_array_equal(splits["test"].attention[index], episode.attention)
    assert [p.name for p in out.parent.iterdir()] == ["hc.h5"]  # no temporary file left
    # schema 2: the two main cars (green, brown: slots 0 and 1) are the focal agents
    assert meta.schema_version == 2 and meta.recorded == OPTIONAL_FIELDS
    for data in splits.values():
        assert data.focal[:, :2].all() and not data.focal[:, 2:].any()
        assert (data.roles[data.focal] < 2).all() and (data.roles[~data.focal] == 2).all()


def test_same_config_same_data_for_any_worker_count(tmp_path):
    config = GenerateConfig.for_scenario("double_merge_v0", num_major=6, num_minor=3, num_test=4)
    generate_dataset(config, tmp_path / "a.h5", progress=False)
    generate_dataset(config, tmp_path / "b.h5", progress=False)
    generate_dataset(config, tmp_path / "c.h5", workers=2, progress=False)
    other_seed = dataclasses.replace(config, seed=1)
    generate_dataset(other_seed, tmp_path / "d.h5", workers=3, progress=False)
    _, a = read_dataset(tmp_path / "a.h5")
    for other in ("b.h5", "c.h5"):
        _, b = read_dataset(tmp_path / other)
        for split in a:
            for name, array in a[split].arrays().items():
                np.testing.assert_array_equal(
                    array, b[split].arrays()[name], err_msg=f"{split}.{name}"
                )
    _, d = read_dataset(tmp_path / "d.h5")
    assert not np.array_equal(a["train"].states, d["train"].states)
    assert d["train"].seed[0] == generation.SEED_STRIDE


@pytest.mark.parametrize("name", ["double_merge_v1", "halting_car_v1"])
def test_batched_generation_writes_the_same_bytes_as_one_by_one(tmp_path, name):
    config = GenerateConfig.for_scenario(name, num_major=12, num_minor=5, num_test=6)  # 34 slots
    generate_dataset(config, tmp_path / "one_by_one.h5", progress=False, batch_scenes=1)
    expected = (tmp_path / "one_by_one.h5").read_bytes()
    for workers, batch_scenes in ((1, 5), (2, 5), (1, 64), (2, 64)):
        out = tmp_path / f"w{workers}_b{batch_scenes}.h5"
        generate_dataset(config, out, workers=workers, progress=False, batch_scenes=batch_scenes)
        assert out.read_bytes() == expected, (workers, batch_scenes)
    with pytest.raises(ValueError, match="batch_scenes must be at least 1"):
        generate_dataset(config, tmp_path / "x.h5", progress=False, batch_scenes=0)


def test_master_seeds_whose_trajectory_seeds_overflow_int64_are_refused():
    top, stride = generation.MAX_SEED, generation.SEED_STRIDE  # seeds stride * seed + k, k < stride
    assert top * stride + stride <= 2**63 - 1 < (top + 1) * stride + stride
    GenerateConfig.for_scenario("halting_car_v0", seed=generation.MAX_SEED)
    with pytest.raises(ValueError, match="seed must be at most"):
        GenerateConfig.for_scenario("halting_car_v0", seed=generation.MAX_SEED + 1)


def test_refuses_to_overwrite_before_any_work(tmp_path, monkeypatch):
    out = tmp_path / "x.h5"
    out.write_bytes(b"precious")

    def no_work(*args, **kwargs):
        raise AssertionError("generation started although the output exists")

    monkeypatch.setattr(generation, "generate_episodes", no_work)
    config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)
    with pytest.raises(FileExistsError, match="overwrite"):
        generate_dataset(config, out, progress=False)
    with pytest.raises(IsADirectoryError):
        generate_dataset(config, tmp_path, overwrite=True, progress=False)
    with pytest.raises(ValueError, match="workers must be at least 1"):
        generate_dataset(config, tmp_path / "y.h5", workers=0, progress=False)
    assert out.read_bytes() == b"precious"
    monkeypatch.undo()
    result = generate_dataset(config, out, overwrite=True, progress=False)
    assert result.path == out and read_meta(out).scenario == "halting_car_v0"


def patch_episodes(monkeypatch, change) -> None:
    """Make the generator's episodes `change(episode)`, whatever the batch size."""

    def batch(scenario, seeds, cases):
        return [change(episode) for episode in rollout_batch(scenario, seeds, cases)]

    monkeypatch.setattr(episode_runner, "rollout_batch", batch)


@pytest.mark.parametrize("batch_scenes", [1, 3, 64])
def test_unsafe_episodes_are_replaced_deterministically(monkeypatch, batch_scenes):
    bad_seeds = {2, 5}

    def flag(episode):
        return dataclasses.replace(episode, collided=episode.seed in bad_seeds)

    patch_episodes(monkeypatch, flag)
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=4, num_minor=2, num_test=1)
    slots, episodes, rejected = generation.generate_episodes(config, batch_scenes=batch_scenes)
    assert rejected == 2
    seeds = [slot.seed for slot in slots]
    assert not bad_seeds & set(seeds)
    assert seeds[2] == len(seeds) and seeds[5] == len(seeds) + 1  # fresh seeds, in slot order
    assert all(generation.is_safe(e) for e in episodes)
    assert [e.seed for e in episodes] == seeds


@pytest.mark.parametrize("batch_scenes", [1, 64])
def test_always_unsafe_expert_gives_up_with_a_clear_error(monkeypatch, batch_scenes):
    patch_episodes(monkeypatch, lambda episode: dataclasses.replace(episode, off_road=True))
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=2, num_minor=0, num_test=0)
    with pytest.raises(generation.UnsafeExpertError, match="still unsafe after 5 rounds"):
        generation.generate_episodes(config, batch_scenes=batch_scenes)


def test_is_safe_rejects_nan_and_off_road():
    states = np.zeros((3, 2, 4))
    good = SimpleNamespace(
        states=states, actions=np.zeros((3, 2, 2)), collided=False, off_road=False
    )
    assert generation.is_safe(good)
    nan_states = states.copy()
    nan_states[1, 0, 0] = np.nan
    assert not generation.is_safe(SimpleNamespace(**{**vars(good), "states": nan_states}))
    assert not generation.is_safe(SimpleNamespace(**{**vars(good), "off_road": True}))
    assert not generation.is_safe(SimpleNamespace(**{**vars(good), "collided": True}))


# ---- interrupts inside the library -------------------------------------------------------------
def _rollout_that_signals(monkeypatch, on_call: int) -> list[int]:
    """Patch the rollout so that episode `on_call` (rolled out one by one, batch_scenes=1)
    sends SIGINT to this process before rolling out."""
    calls: list[int] = []

    def signalling_rollout(scenario, seeds, cases):
        assert len(seeds) == 1
        calls.extend(seeds)
        if len(calls) == on_call:
            os.kill(os.getpid(), signal.SIGINT)  # handled during the episode below
        return rollout_batch(scenario, seeds, cases)

    monkeypatch.setattr(episode_runner, "rollout_batch", signalling_rollout)
    return calls


def test_ctrl_c_reaches_the_caller_after_the_episode_and_writes_nothing(tmp_path, monkeypatch):
    calls = _rollout_that_signals(monkeypatch, on_call=3)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(config, tmp_path / "x.h5", progress=False, batch_scenes=1)
    assert len(calls) == 3  # delivered between episodes, not lost inside one
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert list(tmp_path.iterdir()) == []


def test_a_callers_own_handler_gets_the_signal_between_episodes(tmp_path, monkeypatch):
    calls = _rollout_that_signals(monkeypatch, on_call=2)
    received = []

    def note(signum, frame):
        received.append((signum, len(calls)))  # returns: the caller chose to carry on

    previous = signal.signal(signal.SIGINT, note)
    try:
        config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)
        result = generate_dataset(config, tmp_path / "x.h5", progress=False, batch_scenes=1)
        assert signal.getsignal(signal.SIGINT) is note
    finally:
        signal.signal(signal.SIGINT, previous)
    assert received == [(signal.SIGINT, 2)]
    assert result.path.is_file() and len(calls) == len(plan(config))


def test_ctrl_c_reaches_the_caller_after_the_batch_and_writes_nothing(tmp_path, monkeypatch):
    batches: list[int] = []

    def signalling_batch(scenario, seeds, cases):
        batches.append(len(seeds))
        if len(batches) == 2:
            os.kill(os.getpid(), signal.SIGINT)  # handled during the batch below
        return rollout_batch(scenario, seeds, cases)

    monkeypatch.setattr(episode_runner, "rollout_batch", signalling_batch)
    config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)  # 13 slots: 4 + 4 + 4 + 1
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(config, tmp_path / "x.h5", progress=False, batch_scenes=4)
    assert batches == [4, 4]  # delivered after the second batch, not lost inside it
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_in_a_sharded_run_leaves_nothing(tmp_path, monkeypatch):
    calls = _rollout_that_signals(monkeypatch, on_call=6)  # after two shards were written
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    config = GenerateConfig.for_scenario("halting_car_v0", **SMALL)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(config, tmp_path / "out", progress=False, shard_size=2, batch_scenes=1)
    assert len(calls) == 6
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert list(tmp_path.iterdir()) == []


def test_a_stopping_pool_worker_ends_its_chunk_after_the_current_batch(monkeypatch):
    stop = threading.Event()  # a worker's view of the pool's stop event
    batches: list[int] = []

    def batch_then_stop(scenario, seeds, cases):
        batches.append(len(seeds))
        stop.set()  # the parent stops the pool while this batch runs
        return rollout_batch(scenario, seeds, cases)

    monkeypatch.setattr(episode_runner, "_STOP", stop)
    monkeypatch.setattr(episode_runner, "_SCENARIO", VERSIONS["halting_car_v0"].make())
    monkeypatch.setattr(episode_runner, "rollout_batch", batch_then_stop)
    slots = plan(GenerateConfig.for_scenario("halting_car_v0", **SMALL))[:12]
    assert episode_runner._run_chunk((slots, 4)) == []  # no result is used once stopping
    assert batches == [4]  # the batch under way finished; the other two never started
    assert episode_runner._run_chunk((slots, 4)) == [] and batches == [4]  # queued: at once


def test_ctrl_c_stops_a_pool_of_workers_and_reaches_the_caller():
    class SignalOnSecondCheck:
        checks = 0

        def check(self) -> None:
            self.checks += 1
            if self.checks == 2:
                raise KeyboardInterrupt

    slots = plan(GenerateConfig.for_scenario("halting_car_v0", num_major=40, num_test=0))
    signals = SignalOnSecondCheck()
    progress = SimpleNamespace(update=lambda n: None)
    with pytest.raises(KeyboardInterrupt):  # the pool is closed and joined, not left hanging
        episode_runner.run_slots(slots, "halting_car_v0", 2, progress, signals, batch_scenes=4)
    assert signals.checks == 2
