"""Sharded datasets: a folder of dataset files (shards) and an index that reads as one file.

    with ShardedWriter("data/big", shard_meta) as writer:
        writer.write_shard("train", 0, first_block)  # positions in any order
        ...
        index = writer.finish(meta)  # data/big/index.h5: read_dataset(index) sees one dataset

Layout (docs/dataset_format.md, "Sharded datasets"):

    FOLDER/index.h5           schema 3: the whole dataset's root attributes, `shards`, and per split
                              and array an HDF5 virtual dataset over the shards' rows, in order
    FOLDER/train-00000.h5     schema 2: a complete file holding one block of one split's
    FOLDER/train-00001.h5     trajectories (its other splits empty), readable on its own
    FOLDER/val-00000.h5 ...

The virtual datasets name their shards by bare file name, resolved beside the index, so the folder
can be moved or copied whole. Why a folder: it is written under a temporary name beside the
target and renamed at the end, one atomic step, so an interrupted write leaves nothing at the
target and a reader never meets an index without its shards. h5py and numpy only.
"""

from __future__ import annotations

import dataclasses
import json
import os
import secrets
import shutil
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from trajectory_data.format import (
    FIELDS,
    FORMAT_NAME,
    INDEX_SCHEMA_VERSION,
    NEUTRAL_VALUES,
    SPLITS,
    DatasetMeta,
    FormatError,
    TrajectorySet,
    _write_root_attrs,
    _write_split,
    write_dataset,
)

INDEX_NAME = "index.h5"  # the file a sharded dataset is opened by: FOLDER/index.h5


def shard_name(split: str, position: int) -> str:
    """File name of a split's shard at `position` (0-based), e.g. "train-00003.h5"."""
    return f"{split}-{position:05d}.h5"


def is_sharded_dataset(folder: str | os.PathLike) -> bool:
    """Whether `folder` is a directory holding an index file that `ShardedWriter` wrote (this
    format's schema 3): only such a folder is ever replaced with `overwrite`."""
    index = Path(folder) / INDEX_NAME
    if not index.is_file():
        return False
    try:
        with h5py.File(index, "r") as file:
            kind, version = file.attrs.get("format"), file.attrs.get("schema_version")
    except OSError:
        return False
    return kind == FORMAT_NAME and version is not None and int(version) == INDEX_SCHEMA_VERSION


def check_target(folder: str | os.PathLike, overwrite: bool) -> None:
    """Raise FileExistsError if something is at `folder` and not `overwrite`, and
    IsADirectoryError if it is a directory that is not a sharded dataset (never replaced)."""
    folder = Path(folder)
    if not (folder.exists() or folder.is_symlink()):
        return
    if not overwrite:
        raise FileExistsError(f"output {folder} already exists; pass overwrite=True to replace it")
    if folder.is_dir() and not is_sharded_dataset(folder):
        raise IsADirectoryError(f"output {folder} is a directory but not a sharded dataset")


@dataclass(frozen=True)
class _Shard:
    split: str
    position: int
    count: int  # trajectories
    shapes: dict[str, tuple[int, ...]]  # dataset name -> shape


class ShardedWriter:
    """Context manager writing a sharded dataset into `folder` (see the module); atomic.

    Args:
        folder: the output folder; its parent must exist.
        shard_meta: the metadata every shard carries (the shard's split and position are added
            to its `config` under "shard"); `finish` takes the whole dataset's metadata, which
            may differ from it in `config` only (e.g. totals known only at the end).
        overwrite: replace an existing output (a file, or a sharded dataset's folder).
    Leaving the block without `finish` (an exception, Ctrl-C) removes everything written.
    Raises what `check_target` raises on entering, FileNotFoundError for a missing parent.
    """

    def __init__(
        self, folder: str | os.PathLike, shard_meta: DatasetMeta, *, overwrite: bool = False
    ) -> None:
        shard_meta.validate(source="metadata")
        self.target = Path(folder)
        self.shard_meta = shard_meta
        self.overwrite = overwrite
        self._temp: Path | None = None
        self._shards: dict[tuple[str, int], _Shard] = {}

    def __enter__(self) -> ShardedWriter:
        check_target(self.target, self.overwrite)
        if not self.target.parent.is_dir():
            raise FileNotFoundError(f"output directory {self.target.parent} does not exist")
        temp = self.target.with_name(f".{self.target.name}.{secrets.token_hex(6)}.tmp")
        temp.mkdir()
        self._temp = temp
        return self

    def __exit__(self, *exc: object) -> None:
        if self._temp is not None:  # not finished
            shutil.rmtree(self._temp, ignore_errors=True)
            self._temp = None

    def write_shard(self, split: str, position: int, data: TrajectorySet) -> Path:
        """Write `data` (at least one trajectory) as shard `position` of `split`; returns its path
        (inside the temporary folder until `finish`)."""
        if self._temp is None:
            raise RuntimeError("write_shard is only possible inside the writer's with block")
        if split not in SPLITS:
            raise FormatError(f"unknown split {split!r}; expected one of {list(SPLITS)}")
        if (split, position) in self._shards or position < 0:
            raise ValueError(f"shard {position} of {split} is written twice or negative")
        if data.n == 0:
            raise FormatError(f"shard {position} of {split} holds no trajectory")
        config = {**self.shard_meta.config, "shard": {"split": split, "index": position}}
        meta = dataclasses.replace(self.shard_meta, config=config)
        path = write_dataset(self._temp / shard_name(split, position), meta, {split: data})
        shapes = {name: array.shape for name, array in data.arrays().items()}
        self._shards[split, position] = _Shard(split, position, data.n, shapes)
        return path

    def finish(self, meta: DatasetMeta) -> Path:
        """Write the index with `meta` and move the folder into place; returns the index path.

        Raises FormatError if `meta` differs from the shards' beyond `config`, a split misses a
        position below its last, or a split's shards differ in shape beyond their lengths.
        """
        if self._temp is None:
            raise RuntimeError("finish is only possible inside the writer's with block, once")
        meta.validate(source="metadata")
        if dataclasses.replace(meta, config=self.shard_meta.config) != self.shard_meta:
            raise FormatError("the index's metadata differs from its shards' beyond config")
        if not self._shards:
            raise FormatError("no shard written")
        parts = {split: self._parts(split) for split in SPLITS}
        with h5py.File(self._temp / INDEX_NAME, "x") as file:
            _write_root_attrs(file, meta)
            file.attrs["schema_version"] = np.int64(INDEX_SCHEMA_VERSION)
            listed = [
                {"file": shard_name(s.split, s.position), "split": s.split, "count": s.count}
                for split in SPLITS
                for s in parts[split]
            ]
            file.attrs["shards"] = json.dumps(listed)
            agents = next(iter(self._shards.values())).shapes["states"][2]
            for split in SPLITS:
                self._write_index_split(file.create_group(split), split, parts[split], meta, agents)
        self._commit()
        return self.target / INDEX_NAME

    def _parts(self, split: str) -> list[_Shard]:
        parts = sorted(
            (s for s in self._shards.values() if s.split == split), key=lambda s: s.position
        )
        if [s.position for s in parts] != list(range(len(parts))):
            raise FormatError(
                f"split {split!r} misses a shard before position {parts[-1].position}"
            )
        if len({tuple(s.shapes[n][1:] for n in FIELDS) for s in parts}) > 1:
            raise FormatError(f"the shards of split {split!r} differ in T, N or channels")
        return parts

    @staticmethod
    def _write_index_split(
        group: h5py.Group, split: str, parts: list[_Shard], meta: DatasetMeta, agents: int
    ) -> None:
        """Virtual datasets over the shards' rows; an empty split as in a single file."""
        if not parts:
            channels = len(meta.state_names), len(meta.action_names)
            empty = TrajectorySet.empty(meta.num_steps, agents, *channels)
            _write_split(group, empty, meta.recorded)
            return
        total = sum(s.count for s in parts)
        group.attrs["count"] = np.int64(total)
        for name, (dtype, _) in FIELDS.items():
            if name in NEUTRAL_VALUES and name not in meta.recorded:
                continue
            sources = [(shard_name(split, s.position), s.count) for s in parts]
            _create_virtual(group, name, dtype, parts[0].shapes[name][1:], sources)

    def _commit(self) -> None:
        """Rename the temporary folder onto the target; an existing output is moved aside first
        and removed after (a crash between the two renames leaves it under a .old name)."""
        check_target(self.target, self.overwrite)  # again: something may have appeared since
        aside = None
        if self.target.exists() or self.target.is_symlink():
            aside = self.target.with_name(f".{self.target.name}.{secrets.token_hex(6)}.old")
            os.replace(self.target, aside)
        os.replace(self._temp, self.target)
        self._temp = None
        if aside is not None:
            if aside.is_dir() and not aside.is_symlink():
                shutil.rmtree(aside, ignore_errors=True)
            else:
                aside.unlink(missing_ok=True)


def _create_virtual(
    group: h5py.Group,
    name: str,
    dtype: np.dtype,
    tail: tuple[int, ...],
    sources: list[tuple[str, int]],
) -> None:
    """A virtual dataset `name` stacking the dataset of the same path in each source file (file
    name, rows) along its first axis. Built with h5py's low-level calls rather than
    `Group.create_virtual_dataset`, which records the creation time: without it, the same data
    gives the same bytes."""
    shape = (sum(rows for _, rows in sources), *tail)
    dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
    dcpl.set_obj_track_times(False)
    source_name = f"{group.name}/{name}".encode()
    start = 0
    for file, rows in sources:
        target = h5py.h5s.create_simple(shape)
        target.select_hyperslab((start,) + (0,) * len(tail), (rows, *tail))
        dcpl.set_virtual(target, file.encode(), source_name, h5py.h5s.create_simple((rows, *tail)))
        start += rows
    datatype = h5py.h5t.py_create(np.dtype(dtype), logical=True)
    h5py.h5d.create(group.id, name.encode(), datatype, h5py.h5s.create_simple(shape), dcpl=dcpl)
