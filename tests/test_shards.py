"""Sharded datasets (trajectory_data.shards, and the schema-3 checks of
trajectory_data.format): an index reads exactly as the single file of the same arrays would, through
our reader and through h5py itself; every shard is a valid file alone; the folder can be moved; a
missing, foreign or damaged shard is one line naming it; writing is atomic and never replaces what
it should not."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import assert_sets_equal, make_meta, make_trajectory_set, one_line

from trajectory_data.format import SPLITS, FormatError, TrajectorySet, write_dataset
from trajectory_data.reader import read_dataset, read_meta, read_split, shard_files, summarize
from trajectory_data.shards import INDEX_NAME, ShardedWriter, shard_name

COUNTS = {"train": 7, "val": 0, "test": 3}  # an empty split, and sizes 3 does not divide


def make_splits(num_agents: int = 4) -> dict[str, TrajectorySet]:
    steps = make_meta().num_steps
    return {
        split: make_trajectory_set(n, steps, num_agents, seed=i + 1)
        for i, (split, n) in enumerate(COUNTS.items())
    }


def write_sharded(folder: Path, splits: dict, shard_size: int, **kwargs) -> Path:
    """Cut each split into consecutive blocks of `shard_size`, written last block first."""
    meta = make_meta()
    with ShardedWriter(folder, meta, **kwargs) as writer:
        for split, data in splits.items():
            starts = list(range(0, data.n, shard_size))
            for position, start in reversed(list(enumerate(starts))):
                writer.write_shard(split, position, data.subset(slice(start, start + shard_size)))
        return writer.finish(meta)


@pytest.fixture
def sharded(tmp_path: Path) -> tuple[Path, dict[str, TrajectorySet]]:
    splits = make_splits()
    return write_sharded(tmp_path / "big", splits, shard_size=3), splits


def test_index_reads_as_the_single_file_would(sharded, tmp_path: Path) -> None:
    index, splits = sharded
    single = write_dataset(tmp_path / "single.h5", make_meta(), splits)
    meta, read_back = read_dataset(index)
    single_meta, single_splits = read_dataset(single)
    assert meta.schema_version == 3 and single_meta.schema_version == 2
    assert dataclasses.replace(meta, schema_version=2) == single_meta
    for split in SPLITS:
        assert_sets_equal(read_back[split], single_splits[split])
        assert_sets_equal(read_split(index, split), splits[split])
    with h5py.File(index, "r") as file, h5py.File(single, "r") as other:  # h5py alone, too
        assert {k: v for k, v in file.attrs.items() if k not in ("schema_version", "shards")} == {
            k: v for k, v in other.attrs.items() if k != "schema_version"
        }
        assert file["train/states"].is_virtual
        # no creation times recorded (h5py's create_virtual_dataset would): same data, same bytes
        for split in SPLITS:
            for dataset in file[split].values():
                assert h5py.h5o.get_info(dataset.id).ctime == 0
        np.testing.assert_array_equal(file["train/states"][2:5], other["train/states"][2:5])


def test_layout_and_every_shard_is_a_valid_file_alone(sharded) -> None:
    index, splits = sharded
    names = ["train-00000.h5", "train-00001.h5", "train-00002.h5", "test-00000.h5"]
    assert sorted(p.name for p in index.parent.iterdir()) == sorted([INDEX_NAME, *names])
    assert [p.name for p in shard_files(index)] == names
    assert not [p for p in index.parent.parent.iterdir() if p.name.startswith(".")]  # no temp
    for position, rows in enumerate(((0, 3), (3, 6), (6, 7))):
        meta, alone = read_dataset(index.parent / shard_name("train", position))
        assert meta.schema_version == 2
        assert meta.config["shard"] == {"split": "train", "index": position}
        assert_sets_equal(alone["train"], splits["train"].subset(slice(*rows)))
        assert alone["val"].n == alone["test"].n == 0
    assert "index of 4 shards" in summarize(index)


def test_moved_folder_stays_readable_from_anywhere(sharded, tmp_path: Path, monkeypatch) -> None:
    index, splits = sharded
    moved = tmp_path / "elsewhere" / "renamed"
    moved.parent.mkdir()
    shutil.move(index.parent, moved)
    decoy = tmp_path / "cwd"  # a file of a shard's name in the working directory is not used
    decoy.mkdir()
    shutil.copy(moved / "test-00000.h5", decoy / "train-00000.h5")
    monkeypatch.chdir(decoy)
    _, read_back = read_dataset(moved / INDEX_NAME)
    for split in SPLITS:
        assert_sets_equal(read_back[split], splits[split])


def test_missing_shard_is_one_line_naming_it(sharded) -> None:
    index, _ = sharded
    (index.parent / "train-00001.h5").unlink()
    for read in (read_meta, lambda path: read_split(path, "test")):
        with pytest.raises(FormatError, match="missing shard train-00001.h5") as err:
            read(index)
        assert one_line(err).startswith(f"{index}: ")


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("foreign", "shard train-00001.h5: is not block 1 of train"),
        ("swapped", "shard train-00000.h5: is not block 0 of train"),
        ("reshaped", r"shard train-00001.h5: train/states is float32 \(1, 10, 4, 4\), the index "),
        ("truncated", "shard train-00001.h5: not a readable HDF5 file"),
        ("chunk", "split 'train': shard train-00001.h5: corrupt or truncated data"),
    ],
)
def test_damaged_shard_is_one_line_naming_it(sharded, damage: str, message: str) -> None:
    index, splits = sharded
    shard = index.parent / "train-00001.h5"
    if damage == "foreign":  # a valid dataset file, but not one of this index's shards
        shard.unlink()
        write_dataset(shard, make_meta(), {"train": splits["train"].subset(slice(0, 1))})
    elif damage == "swapped":  # two shards of the same shape, exchanged
        first = index.parent / "train-00000.h5"
        with h5py.File(first, "r") as a, h5py.File(shard, "r") as b:
            assert a["train/states"].shape == b["train/states"].shape
        swap = index.parent / "swap"
        first.rename(swap)
        shard.rename(first)
        swap.rename(shard)
    elif damage == "reshaped":  # labelled as the right block, holding other rows
        with h5py.File(shard, "r") as file:
            attrs = dict(file.attrs)
        shard.unlink()
        write_dataset(shard, make_meta(), {"train": splits["train"].subset(slice(0, 1))})
        with h5py.File(shard, "r+") as file:
            file.attrs["config"] = attrs["config"]
    elif damage == "truncated":
        shard.write_bytes(shard.read_bytes()[:1000])
    else:  # flip bytes inside the last compressed chunk of the shard
        data = bytearray(shard.read_bytes())
        with h5py.File(shard, "r") as file:
            offset = file["train/states"].id.get_chunk_info(2).byte_offset
        data[offset + 10 : offset + 60] = bytes(b ^ 0xFF for b in data[offset + 10 : offset + 60])
        shard.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=message) as err:
        read_dataset(index)
    assert one_line(err).startswith(f"{index}: ")


def test_an_interrupted_write_leaves_nothing(tmp_path: Path) -> None:
    splits = make_splits()
    with pytest.raises(KeyboardInterrupt):
        with ShardedWriter(tmp_path / "big", make_meta()) as writer:
            writer.write_shard("train", 0, splits["train"])
            raise KeyboardInterrupt
    with pytest.raises(FormatError, match="misses a shard before position 2"):
        with ShardedWriter(tmp_path / "big", make_meta()) as writer:
            writer.write_shard("train", 2, splits["train"])
            writer.finish(make_meta())
    assert list(tmp_path.iterdir()) == []


def test_refuses_existing_outputs_and_never_replaces_a_foreign_folder(tmp_path: Path) -> None:
    splits = make_splits()
    first = write_sharded(tmp_path / "big", splits, shard_size=3)
    stamp = first.read_bytes()
    with pytest.raises(FileExistsError, match="overwrite"):
        write_sharded(tmp_path / "big", splits, shard_size=5)
    assert first.read_bytes() == stamp and len(shard_files(first)) == 4
    again = write_sharded(tmp_path / "big", splits, shard_size=5, overwrite=True)
    assert len(shard_files(again)) == 3  # 5 + 2 train, 3 test
    _, read_back = read_dataset(again)
    assert_sets_equal(read_back["train"], splits["train"])
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("keep")
    with pytest.raises(IsADirectoryError, match="not a sharded dataset"):
        write_sharded(precious, splits, shard_size=3, overwrite=True)
    assert (precious / "notes.txt").read_text() == "keep"
    # a folder whose index.h5 is some other file (or another format's) is not ours either
    (precious / INDEX_NAME).write_bytes(b"not hdf5")
    with pytest.raises(IsADirectoryError, match="not a sharded dataset"):
        write_sharded(precious, splits, shard_size=3, overwrite=True)
    (precious / INDEX_NAME).unlink()
    write_dataset(precious / INDEX_NAME, make_meta(), {"train": splits["train"]})  # schema 2
    with pytest.raises(IsADirectoryError, match="not a sharded dataset"):
        write_sharded(precious, splits, shard_size=3, overwrite=True)
    assert (precious / "notes.txt").read_text() == "keep"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big", "precious"]


def test_index_meta_must_match_its_shards_beyond_config(tmp_path: Path) -> None:
    splits = make_splits()
    meta = make_meta()
    with pytest.raises(FormatError, match="beyond config"):
        with ShardedWriter(tmp_path / "big", meta) as writer:
            writer.write_shard("train", 0, splits["train"])
            writer.finish(dataclasses.replace(meta, dt=0.2))
    with ShardedWriter(tmp_path / "big", meta) as writer:  # config may differ: totals
        writer.write_shard("train", 0, splits["train"])
        index = writer.finish(dataclasses.replace(meta, config={"total": 7}))
    assert read_meta(index).config == {"total": 7}
    assert os.path.isfile(index)
