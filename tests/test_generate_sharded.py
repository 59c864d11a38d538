"""Sharded generation (--shard-size): the index and each shard read as the single file of the
same config, for any worker count, with replacements, interrupts and the tools on the index."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import load_tool, run_tool

from pipeline import episode_runner
from pipeline.generation import GenerateConfig, generate_dataset, plan
from scenarios.rollout import rollout_batch
from trajectory_data.reader import read_dataset, read_split

generate_tool = load_tool("generate.py")


def run_generate(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return run_tool("generate.py", *args, timeout=timeout)


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
    config = GenerateConfig.for_scenario("double_merge_v0", **SHARDED)
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

    from trajectory_data.torch_dataset import TrajectoryDataset, make_loader

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
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=4, num_minor=1, num_test=2)
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

    def flaky_rollout(scenario, seeds, cases):
        episodes = rollout_batch(scenario, seeds, cases)
        return [dataclasses.replace(e, collided=e.seed in bad_seeds) for e in episodes]

    monkeypatch.setattr(episode_runner, "rollout_batch", flaky_rollout)
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=4, num_minor=2, num_test=1)
    assert len(plan(config)) == plan_length
    # one by one (batch_scenes=1)
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


def test_cli_sharded_smoke_refusals_and_tools_on_the_index(tmp_path, sharded_pair):
    out = tmp_path / "hc"
    args = ["--scenario", "halting_car_v0", "--num-major", "3", "--num-test", "2"]
    args += ["--shard-size", "2", "--out", str(out)]
    result = run_generate(*args)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"wrote {out / 'index.h5'} and 5 shards: train 2 stop + 1 go;")
    stamps = {p.name: p.read_bytes() for p in out.iterdir()}
    again = run_generate(*args)
    assert again.returncode == 2
    assert again.stderr.strip().splitlines()[-1] == (
        f"error: output {out} already exists; pass --overwrite to replace it"
    )
    assert {p.name: p.read_bytes() for p in out.iterdir()} == stamps
    # the tools read the index as the single file (the table of evaluate.py is the same)
    index, single, _ = sharded_pair
    inspected = run_tool("inspect_data.py", index)
    assert inspected.returncode == 0, inspected.stderr
    assert "index of 7 shards" in inspected.stdout and "valid schema v3 dataset" in inspected.stdout
    tables = []
    for data in (index, single):
        evaluated = run_tool("evaluate.py", "--baseline", "const_vel", "--data", data)
        assert evaluated.returncode == 0, evaluated.stderr
        assert "evaluate const_vel" in evaluated.stderr  # its progress bar
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
            ["--scenario", "halting_car_v0", "--num-major", "1", "--shard-size", "2"] + argv
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
    inspected = run_tool("inspect_data.py", copy / "index.h5")
    assert inspected.returncode == 2 and inspected.stdout == ""
    assert inspected.stderr.splitlines() == [
        f"error: {copy / 'index.h5'}: missing shard val-00000.h5 (expected beside the index)"
    ]
