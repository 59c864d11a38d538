"""Dataset generation: pipeline.generation (config validation, counts, determinism across runs
and workers, atomicity, refusing to overwrite, interrupts) and tools/generate.py (CLI)."""

from __future__ import annotations

import dataclasses
import errno
import importlib.util
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import load_tool

from pipeline import episode_runner, generation
from pipeline.generation import GenerateConfig, default_output, generate_dataset, plan
from predictor.format import OPTIONAL_FIELDS
from predictor.format_reader import read_dataset, read_meta, read_split
from scenarios import SCENARIOS
from scenarios.batched_rollout import rollout_batch
from scenarios.rollout import rollout

REPO = Path(__file__).resolve().parents[1]
TOOL = REPO / "tools" / "generate.py"
generate_tool = load_tool("generate.py")

SMALL = dict(num_major=5, num_minor=2, num_test=3)  # 4 + 1 major, 2 + 0 minor, 3 + 3 test


def run_tool(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(TOOL), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def counts(config: GenerateConfig) -> dict[tuple[str, str], int]:
    tally: dict[tuple[str, str], int] = {}
    for slot in plan(config):
        tally[(slot.split, slot.case)] = tally.get((slot.split, slot.case), 0) + 1
    return tally


# ---- config ------------------------------------------------------------------------------------
def test_default_counts_follow_the_paper():
    config = GenerateConfig.for_scenario("double_merge", minor_ratio=0.3)
    assert (config.major_case, config.minor_case) == ("major", "minor")
    assert counts(config) == {
        ("train", "major"): 40,
        ("val", "major"): 10,
        ("train", "minor"): 12,
        ("val", "minor"): 3,
        ("test", "major"): 50,
        ("test", "minor"): 50,
    }
    assert GenerateConfig.for_scenario("double_merge") == config  # 0.3 is the default ratio


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
    config = GenerateConfig.for_scenario("halting_car", **kwargs)
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
    args = generate_tool.parse_args(["--scenario", "double_merge"])
    assert generate_tool.config_from_args(args).scenario == "double_merge"


def test_go_as_major_case_and_cli_builds_the_same_config():
    config = GenerateConfig.for_scenario("halting_car", major_case="go", num_major=7, seed=2)
    assert (config.major_case, config.minor_case, config.num_minor) == ("go", "stop", 2)
    args = generate_tool.parse_args(
        ["--scenario", "halting_car", "--major-case", "go", "--num-major", "7", "--seed", "2"]
    )
    assert generate_tool.config_from_args(args) == config
    assert default_output(config) == Path("data/halting_car_go-major_7+2_seed2.h5")


VALID = dict(scenario="halting_car", major_case="stop", minor_case="go")


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(scenario="roundabout"), "scenario"),
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
        (dict(minor_ratio=float("nan")), "minor_ratio"),
        (dict(major_case="major"), "major_case"),
        (dict(num_major=0), "num_major"),
    ],
)
def test_for_scenario_rejects_bad_values(kwargs, text):
    with pytest.raises(ValueError, match=text):
        GenerateConfig.for_scenario("halting_car", **kwargs)


# ---- generate_dataset --------------------------------------------------------------------------
def test_round_trip_file_contents(tmp_path):
    out = tmp_path / "sub" / "hc.h5"  # missing directories are created
    config = GenerateConfig.for_scenario("halting_car", **SMALL)
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
    assert meta.scenario == "halting_car" and meta.major_case == "stop"
    assert meta.config["generator"] == dataclasses.asdict(config)
    assert splits["train"].n == 4 + 2 and splits["val"].n == 1 + 0 and splits["test"].n == 6
    case_names = list(meta.case_names)
    test_cases = [case_names[i] for i in splits["test"].case]
    assert test_cases == ["stop"] * 3 + ["go"] * 3
    # the stored arrays are exactly what the scenario's rollout gives for the stored seeds
    scenario = SCENARIOS["halting_car"]()
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
    config = GenerateConfig.for_scenario("double_merge", num_major=6, num_minor=3, num_test=4)
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


def test_refuses_to_overwrite_before_any_work(tmp_path, monkeypatch):
    out = tmp_path / "x.h5"
    out.write_bytes(b"precious")

    def no_work(*args, **kwargs):
        raise AssertionError("generation started although the output exists")

    monkeypatch.setattr(generation, "generate_episodes", no_work)
    config = GenerateConfig.for_scenario("halting_car", **SMALL)
    with pytest.raises(FileExistsError, match="overwrite"):
        generate_dataset(config, out, progress=False)
    with pytest.raises(IsADirectoryError):
        generate_dataset(config, tmp_path, overwrite=True, progress=False)
    with pytest.raises(ValueError, match="workers must be at least 1"):
        generate_dataset(config, tmp_path / "y.h5", workers=0, progress=False)
    assert out.read_bytes() == b"precious"
    monkeypatch.undo()
    result = generate_dataset(config, out, overwrite=True, progress=False)
    assert result.path == out and read_meta(out).scenario == "halting_car"


def patch_episodes(monkeypatch, change) -> None:
    """Make the generator's episodes `change(episode)`, on both paths (one by one, batched)."""

    def one(scenario, seed, case):
        return change(rollout(scenario, seed, case))

    def batch(scenario, seeds, cases):
        return [change(episode) for episode in rollout_batch(scenario, seeds, cases)]

    monkeypatch.setattr(episode_runner, "rollout", one)
    monkeypatch.setattr(episode_runner, "rollout_batch", batch)


@pytest.mark.parametrize("batch_scenes", [1, 3, 64])
def test_unsafe_episodes_are_replaced_deterministically(monkeypatch, batch_scenes):
    bad_seeds = {2, 5}

    def flag(episode):
        return dataclasses.replace(episode, collided=episode.seed in bad_seeds)

    patch_episodes(monkeypatch, flag)
    config = GenerateConfig.for_scenario("halting_car", num_major=4, num_minor=2, num_test=1)
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
    config = GenerateConfig.for_scenario("halting_car", num_major=2, num_minor=0, num_test=0)
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
    """Patch rollout so that call `on_call` sends SIGINT to this process before rolling out."""
    calls: list[int] = []

    def signalling_rollout(scenario, seed, case):
        calls.append(seed)
        if len(calls) == on_call:
            os.kill(os.getpid(), signal.SIGINT)  # handled during the episode below
        return rollout(scenario, seed, case)

    monkeypatch.setattr(episode_runner, "rollout", signalling_rollout)
    return calls


def test_ctrl_c_reaches_the_caller_after_the_episode_and_writes_nothing(tmp_path, monkeypatch):
    calls = _rollout_that_signals(monkeypatch, on_call=3)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    config = GenerateConfig.for_scenario("halting_car", **SMALL)
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
        config = GenerateConfig.for_scenario("halting_car", **SMALL)
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
    config = GenerateConfig.for_scenario("halting_car", **SMALL)  # 13 slots: 4 + 4 + 4 + 1
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(config, tmp_path / "x.h5", progress=False, batch_scenes=4)
    assert batches == [4, 4]  # delivered after the second batch, not lost inside it
    assert list(tmp_path.iterdir()) == []


# ---- the command-line tool ---------------------------------------------------------------------
def test_cli_smoke_summary_and_refuses_overwrite(tmp_path):
    out = tmp_path / "dm.h5"
    args = [
        "--scenario",
        "double_merge",
        "--num-major",
        "3",
        "--minor-ratio",
        "0.8",
        "--num-test",
        "2",
        "--out",
        str(out),
    ]
    result = run_tool(*args)
    assert result.returncode == 0, result.stderr
    assert re.fullmatch(
        rf"wrote {re.escape(str(out))}: train 2 major \+ 2 minor; val 1 major \+ 0 minor; "
        r"test 2 major \+ 2 minor \(22 agents, 60 steps of 0.2 s; 0 unsafe episodes replaced\) "
        r"in \d+\.\d s\n",
        result.stdout,
    ), result.stdout
    assert read_meta(out).num_steps > 0
    first = out.read_bytes()
    again = run_tool(*args)
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert out.read_bytes() == first
    replaced = run_tool(*args, "--overwrite", "--seed", "3")
    assert replaced.returncode == 0 and out.read_bytes() != first


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--scenario", "roundabout"], "invalid choice"),
        (["--scenario", "halting_car", "--minor-ratio", "-0.1"], "--minor-ratio"),
        (["--scenario", "halting_car", "--minor-ratio", "1e6"], "--minor-ratio"),
        (["--scenario", "halting_car", "--num-major", "2.5"], "invalid int"),
        (["--scenario", "halting_car", "--num-test", "ten"], "invalid int"),
        (["--scenario", "halting_car", "--num-major", "0"], "--num-major must be at least 1"),
        (["--scenario", "halting_car", "--num-test", "-1"], "--num-test must be at least 0"),
        (["--scenario", "halting_car", "--val-fraction", "1.0"], "--val-fraction"),
        (["--scenario", "halting_car", "--val-fraction", "-0.2"], "--val-fraction"),
        (["--scenario", "halting_car", "--major-case", "major"], "--major-case"),
        (["--scenario", "halting_car", "--seed", "-1"], "seed must be at least 0"),
        (["--scenario", "halting_car", "--workers", "0"], "--workers"),
        (["--scenario", "halting_car", "--batch-scenes", "0"], "--batch-scenes must be at least 1"),
        (["--scenario", "halting_car", "--minor-ratio", "0.3", "--num-minor", "3"], "either"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_file(tmp_path, argv, message):
    out = tmp_path / "x.h5"
    result = run_tool(*argv, "--out", str(out))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in result.stderr
    assert lines[0].startswith("error: ")
    assert list(tmp_path.iterdir()) == []


def test_output_below_a_file_exits_2(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    result = run_tool(
        "--scenario",
        "halting_car",
        "--num-major",
        "2",
        "--num-test",
        "1",
        "--out",
        str(blocker / "sub" / "x.h5"),
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"error: cannot write {blocker / 'sub' / 'x.h5'}: Not a directory: {blocker / 'sub'}"
    ]


def test_unwritable_directory_exits_2(tmp_path, monkeypatch, capsys):
    # root ignores permission bits, so the refusal of a read-only directory is simulated where
    # the file is created: the real write_dataset raises what h5py/os raise there.
    def refuse(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr(generation, "write_dataset", refuse)
    out = tmp_path / "x.h5"
    with pytest.raises(SystemExit) as exit_:
        generate_tool.main(
            ["--scenario", "halting_car", "--num-major", "1", "--num-test", "0"]
            + ["--out", str(out)]
        )
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"error: cannot write {out}: Permission denied"
    assert list(tmp_path.iterdir()) == []


# ---- sharded output (--shard-size): the truth is the single file of the same config ----------
SHARDED = dict(num_major=6, num_minor=3, num_test=4)  # train 5 + 2, val 1 + 1, test 4 + 4


def assert_reads_as(index: Path, single: Path) -> None:
    """The index reads exactly as the single file: metadata (but the schema version) and every
    array of every split, through read_dataset and read_split."""
    meta, splits = read_dataset(index)
    single_meta, single_splits = read_dataset(single)
    assert (meta.schema_version, single_meta.schema_version) == (3, 2)
    assert dataclasses.replace(meta, schema_version=2) == single_meta
    for split, expected in single_splits.items():
        for data in (splits[split], read_split(index, split)):
            for name, array in expected.arrays().items():
                got = data.arrays()[name]
                assert got.dtype == array.dtype, f"{split}.{name}"
                np.testing.assert_array_equal(got, array, err_msg=f"{split}.{name}")


@pytest.fixture(scope="module")
def sharded_pair(tmp_path_factory) -> tuple[Path, Path, GenerateConfig]:
    """A Double Merge dataset as one file and as shards of 3 (which divide no split's count)."""
    root = tmp_path_factory.mktemp("sharded")
    config = GenerateConfig.for_scenario("double_merge", **SHARDED)
    single = generate_dataset(config, root / "single.h5", progress=False)
    sharded = generate_dataset(config, root / "sharded", progress=False, shard_size=3)
    assert sharded.path == root / "sharded" / "index.h5"
    assert (sharded.counts, sharded.rejected, sharded.meta) == (
        single.counts,
        single.rejected,
        single.meta,
    )
    return sharded.path, single.path, config


def test_sharded_output_reads_as_the_single_file_and_each_shard_alone(sharded_pair):
    index, single, _ = sharded_pair
    assert_reads_as(index, single)
    names = sorted(p.name for p in index.parent.iterdir())
    assert names == ["index.h5"] + [f"test-0000{k}.h5" for k in range(3)] + [
        "train-00000.h5",
        "train-00001.h5",
        "train-00002.h5",
        "val-00000.h5",
    ]
    _, whole = read_dataset(single)
    for name in names[1:]:  # each shard is a valid file holding its block of one split
        split, position = name[: -len("-00000.h5")], int(name[-8:-3])
        meta, alone = read_dataset(index.parent / name)
        assert meta.config["shard"] == {"split": split, "index": position}
        rows = slice(3 * position, 3 * position + 3)
        for other in alone:
            expected = whole[split].subset(rows) if other == split else None
            assert alone[other].n == (expected.n if expected else 0)
            if expected:
                np.testing.assert_array_equal(alone[other].states, expected.states)
                np.testing.assert_array_equal(alone[other].seed, expected.seed)


def test_training_loader_gives_the_same_batches_from_the_index(sharded_pair):
    import torch

    from predictor.data import TrajectoryDataset, make_loader

    index, single, _ = sharded_pair
    for split in ("train", "test"):
        a, b = TrajectoryDataset(index, split), TrajectoryDataset(single, split)
        assert a.meta == dataclasses.replace(b.meta, schema_version=3) and len(a) == len(b) > 0
        got = list(make_loader(a, 4, shuffle=True, seed=3))
        want = list(make_loader(b, 4, shuffle=True, seed=3))
        assert len(got) == len(want) == -(-len(b) // 4)
        for mine, theirs in zip(got, want):
            for field in dataclasses.fields(theirs):
                x, y = getattr(mine, field.name), getattr(theirs, field.name)
                assert (x is None) == (y is None) and (x is None or torch.equal(x, y)), field.name


@pytest.mark.parametrize("shard_size", [1, 4, 1000])
def test_shards_are_the_same_bytes_for_any_worker_count(tmp_path, shard_size):
    config = GenerateConfig.for_scenario("halting_car", num_major=4, num_minor=1, num_test=2)
    one = generate_dataset(config, tmp_path / "one", progress=False, shard_size=shard_size)
    two = generate_dataset(
        config, tmp_path / "two", workers=2, progress=False, shard_size=shard_size
    )
    files = sorted(p.name for p in one.path.parent.iterdir())
    assert files == sorted(p.name for p in two.path.parent.iterdir())
    assert len(files) == 1 + one.shards
    for name in files:
        assert (one.path.parent / name).read_bytes() == (two.path.parent / name).read_bytes()
    single = generate_dataset(config, tmp_path / "single.h5", progress=False)
    assert_reads_as(one.path, single.path)


def test_sharded_unsafe_episodes_get_the_single_files_replacement_seeds(tmp_path, monkeypatch):
    plan_length = 8  # train 3 + 2, val 1 + 0, test 1 + 1
    bad_seeds = {2, 5, plan_length}  # slot 2's first replacement is unsafe too

    def flaky_rollout(scenario, seed, case):
        episode = rollout(scenario, seed, case)
        return dataclasses.replace(episode, collided=seed in bad_seeds)

    monkeypatch.setattr(episode_runner, "rollout", flaky_rollout)
    config = GenerateConfig.for_scenario("halting_car", num_major=4, num_minor=2, num_test=1)
    assert len(plan(config)) == plan_length
    # one by one (batch_scenes=1): the patched per-episode rollout is what runs
    single = generate_dataset(config, tmp_path / "single.h5", progress=False, batch_scenes=1)
    assert single.rejected == 3
    assert read_dataset(single.path)[1]["train"].seed.tolist() == [0, 1, 10, 3, 4]
    for shard_size in (1, 2, 3):  # slot 2's shard waits for the second round, the rest not
        sharded = generate_dataset(
            config,
            tmp_path / f"by{shard_size}",
            progress=False,
            shard_size=shard_size,
            batch_scenes=1,
        )
        assert sharded.rejected == 3
        assert_reads_as(sharded.path, single.path)


def test_ctrl_c_in_a_sharded_run_leaves_nothing(tmp_path, monkeypatch):
    calls = _rollout_that_signals(monkeypatch, on_call=6)  # after two shards were written
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    config = GenerateConfig.for_scenario("halting_car", **SMALL)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(config, tmp_path / "out", progress=False, shard_size=2, batch_scenes=1)
    assert len(calls) == 6
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    assert list(tmp_path.iterdir()) == []


def test_cli_sharded_smoke_refusals_and_tools_on_the_index(tmp_path, sharded_pair):
    out = tmp_path / "hc"
    args = ["--scenario", "halting_car", "--num-major", "3", "--num-test", "2"]
    args += ["--shard-size", "2", "--out", str(out)]
    result = run_tool(*args)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"wrote {out / 'index.h5'} and 5 shards: train 2 stop + 1 go;")
    stamps = {p.name: p.read_bytes() for p in out.iterdir()}
    again = run_tool(*args)
    assert again.returncode == 2
    assert again.stderr.strip().splitlines()[-1] == (
        f"error: output {out} already exists; pass --overwrite to replace it"
    )
    assert {p.name: p.read_bytes() for p in out.iterdir()} == stamps
    # the tools read the index as the single file (the table of evaluate.py is the same)
    index, single, _ = sharded_pair
    inspected = subprocess.run(
        [sys.executable, str(REPO / "tools" / "inspect_data.py"), str(index)],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert inspected.returncode == 0, inspected.stderr
    assert "index of 7 shards" in inspected.stdout and "valid schema v3 dataset" in inspected.stdout
    tables = []
    for data in (index, single):
        evaluated = subprocess.run(
            [sys.executable, str(REPO / "tools" / "evaluate.py"), "--baseline", "const_vel"]
            + ["--data", str(data)],
            capture_output=True,
            text=True,
            cwd=REPO,
        )
        assert evaluated.returncode == 0, evaluated.stderr
        tables.append(evaluated.stdout.rsplit(" in ", 1)[0])  # without the timing
    assert tables[0] == tables[1]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--shard-size", "0"], "error: --shard-size must be at least 1, got 0"),
        (["--out", "{tmp}/x.h5"], "error: with --shard-size, --out names a folder"),
        (["--out", "{tmp}", "--overwrite"], "error: output {tmp} is a directory but not a shard"),
    ],
)
def test_cli_sharded_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, message):
    (tmp_path / "notes.txt").write_text("keep")
    argv = [a.format(tmp=tmp_path) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "out")]
    with pytest.raises(SystemExit) as exit_:
        generate_tool.main(
            ["--scenario", "halting_car", "--num-major", "1", "--shard-size", "2"] + argv
        )
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(message.format(tmp=tmp_path))
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


def test_missing_shard_is_one_line_from_the_tools(sharded_pair, tmp_path):
    index, _, _ = sharded_pair
    copy = tmp_path / "copy"
    shutil.copytree(index.parent, copy)
    (copy / "val-00000.h5").unlink()
    inspected = subprocess.run(
        [sys.executable, str(REPO / "tools" / "inspect_data.py"), str(copy / "index.h5")],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert inspected.returncode == 1 and inspected.stdout == ""
    assert inspected.stderr.splitlines() == [
        f"error: {copy / 'index.h5'}: missing shard val-00000.h5 (expected beside the index)"
    ]


# ---- interrupting the tool ---------------------------------------------------------------------
PROGRESS = re.compile(rb"\| *[1-9]\d*/\d+ \[")  # tqdm: at least one trajectory done


def start_and_wait_for_progress(
    out: Path, workers: int, timeout: float = 180, extra: tuple[str, ...] = ()
):
    """Start a long generation; return (process, stderr so far) once a trajectory is done."""
    process = subprocess.Popen(
        [sys.executable, str(TOOL), "--scenario", "double_merge", "--num-major", "5000"]
        + ["--workers", str(workers), "--out", str(out), *extra],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group, like a job in a terminal
    )
    seen = b""
    deadline = time.monotonic() + timeout
    while not PROGRESS.search(seen):
        ready, _, _ = select.select([process.stderr], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(process.stderr.fileno(), 65536) if ready else b""
        if not chunk:  # timed out, or the tool ended
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            pytest.fail(f"no progress within {timeout} s; stderr: {seen[-1000:]!r}")
        seen += chunk
    return process, seen


def group_ends(group: int, within: float) -> bool:
    """Whether process group `group` has no process left within `within` seconds."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


RAY = pytest.param(
    (2, ("--backend", "ray")),
    id="ray",
    marks=pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray not installed"),
)


SHARDS = (2, ("--shard-size", "10"))  # a pool per shard of 10, the temporary folder removed


@pytest.mark.parametrize(
    "run", [(1, ()), (2, ()), SHARDS, RAY], ids=["workers1", "workers2", "shards", "ray"]
)
@pytest.mark.parametrize(
    "sig, to_group",
    [(signal.SIGINT, True), (signal.SIGTERM, False)],
    ids=["ctrl-c-to-the-group", "sigterm-to-the-tool"],
)
def test_interrupted_run_leaves_no_file(tmp_path, sig, to_group, run):
    workers, extra = run
    out = tmp_path / ("big" if "--shard-size" in extra else "big.h5")
    process, seen = start_and_wait_for_progress(out, workers, extra=extra)
    try:
        if to_group:  # what a terminal's Ctrl-C does: the tool and its workers get SIGINT
            os.killpg(process.pid, sig)
        else:
            process.send_signal(sig)
        stdout, rest = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    stderr = (seen + rest).decode()
    assert process.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr and "cffi" not in stderr and "Exception" not in stderr
    lines = [line for line in re.split(r"[\r\n]", stderr) if line.strip()]
    assert lines[-1] == "error: interrupted; nothing was written"
    assert sum("error" in line for line in lines) == 1
    assert stdout == b""
    assert list(tmp_path.iterdir()) == []
    assert group_ends(process.pid, within=10.0)  # no worker (nor Ray process) outlives the tool
