"""Reading the trajectory dataset format (`trajectory_data.format`): schema 1, 2 and 4 files
and schema-3 indexes of shards, each read validated into the in-memory `DatasetMeta` and
`TrajectorySet`, or a one-line `FormatError` naming the file and the problem; and the
human-readable summary of a file (`tools/inspect_data.py`).

The reader upgrades as it reads: a schema-1 file reads as schema 2 with everything recorded and
its first two agent slots focal; a schema-3 index reads like one file once every shard it lists
is checked to be there with the rows, dtypes and shapes it maps.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np

from trajectory_data.format import (
    ACTION_NAMES,
    FIELDS,
    FORMAT_NAME,
    INDEX_SCHEMA_VERSION,
    INFLUENCE,
    INFLUENCE_FIELD,
    INFLUENCE_KINDS,
    INFLUENCE_WINDOW_ATTR,
    INFLUENCE_WINDOWS,
    INFLUENCE_WINDOWS_FIELD,
    MATRIX_FIELDS,
    NEUTRAL_VALUES,
    OPTIONAL_FIELDS,
    RECORDABLE,
    ROOT_ATTRS,
    ROOT_ATTRS_V1,
    ROOT_ATTRS_V3,
    SPLITS,
    STATE_NAMES,
    SUPPORTED_VERSIONS,
    DatasetMeta,
    TrajectorySet,
    format_error,
    legacy_focal,
    versions_text,
)
from trajectory_data.window_summary import influence_window_lines


class _Reader:
    """An open, format-checked file; converts h5py/OS errors into one-line FormatErrors."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.source = str(self.path)
        if not self.path.is_file():
            raise format_error(self.source, "no such file")
        try:
            is_hdf5 = h5py.is_hdf5(self.path)
        except OSError as err:
            raise format_error(self.source, f"cannot read file: {err}") from None
        if not is_hdf5:
            raise format_error(self.source, "not an HDF5 file")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as err:
            raise format_error(
                self.source, f"corrupt or truncated HDF5 file ({_short(err)})"
            ) from None
        # schema 3 (an index): split -> [(shard file name, trajectories)] in row order; set by meta
        self.shards: dict[str, list[tuple[str, int]]] | None = None

    def __enter__(self) -> _Reader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.file.close()

    def meta(self) -> DatasetMeta:
        attrs = self._root_attrs()
        version = self._number(attrs, "schema_version", int)
        if version == 1:  # fixed channels, everything recorded
            for name, expected in (("state_names", STATE_NAMES), ("action_names", ACTION_NAMES)):
                if tuple(self._json(attrs, name, list)) != expected:
                    raise format_error(self.source, f"{name} must be {list(expected)}")
            recorded = OPTIONAL_FIELDS
        else:
            recorded = tuple(self._json(attrs, "recorded", list))
        if version == INDEX_SCHEMA_VERSION:
            self.shards = self._shard_table(attrs)
        meta = DatasetMeta(
            scenario=self._text(attrs, "scenario"),
            dt=self._number(attrs, "dt", float),
            num_observed=self._number(attrs, "num_observed", int),
            num_predicted=self._number(attrs, "num_predicted", int),
            case_names=tuple(self._json(attrs, "case_names", list)),
            major_case=self._text(attrs, "major_case"),
            role_names=tuple(self._json(attrs, "role_names", list)),
            config=self._json(attrs, "config", dict),
            package_version=self._text(attrs, "package_version"),
            schema_version=version,
            state_names=tuple(self._json(attrs, "state_names", list)),
            action_names=tuple(self._json(attrs, "action_names", list)),
            recorded=recorded,
            influence_window_steps=(
                self._number(attrs, INFLUENCE_WINDOW_ATTR, int)
                if INFLUENCE_WINDOW_ATTR in attrs
                else 0
            ),
        )
        meta.validate(self.source)
        return meta

    def _root_attrs(self) -> dict:
        try:
            attrs = dict(self.file.attrs)
        except OSError as err:
            raise format_error(self.source, f"corrupt HDF5 file ({_short(err)})") from None
        if "format" not in attrs:
            raise format_error(self.source, f"not a {FORMAT_NAME} file (no 'format' attribute)")
        if self._text(attrs, "format") != FORMAT_NAME:
            raise format_error(
                self.source, f"format is {attrs['format']!r}, expected {FORMAT_NAME!r}"
            )
        if "schema_version" not in attrs:
            raise format_error(self.source, "missing root attribute 'schema_version'")
        version = self._number(attrs, "schema_version", int)
        if version not in SUPPORTED_VERSIONS:
            raise format_error(
                self.source,
                f"schema_version {version} is not supported (this reader reads {versions_text()})",
            )
        required = {1: ROOT_ATTRS_V1, 2: ROOT_ATTRS, 3: ROOT_ATTRS_V3, 4: ROOT_ATTRS}[version]
        missing = [name for name in required if name not in attrs]
        if missing:
            raise format_error(self.source, f"missing root attribute(s) {missing}")
        return attrs

    def _shard_table(self, attrs: dict) -> dict[str, list[tuple[str, int]]]:
        """An index's root attribute `shards`, by split; every listed file must be beside it."""
        table: dict[str, list[tuple[str, int]]] = {name: [] for name in SPLITS}
        seen = set()
        for entry in self._json(attrs, "shards", list):
            if not isinstance(entry, dict) or sorted(entry) != ["count", "file", "split"]:
                raise format_error(
                    self.source, "attribute 'shards' must list {file, split, count} objects"
                )
            file, split, count = entry["file"], entry["split"], entry["count"]
            if not isinstance(file, str) or Path(file).name != file or file.startswith("."):
                raise format_error(
                    self.source, f"shard {file!r} must be a file name beside the index"
                )
            if split not in SPLITS or file in seen:
                raise format_error(
                    self.source, f"shard {file} has split {split!r} or is listed twice"
                )
            if not isinstance(count, int) or isinstance(count, bool) or count < 1:
                raise format_error(self.source, f"shard {file} has count {count!r}, expected >= 1")
            if not (self.path.parent / file).is_file():
                raise format_error(self.source, f"missing shard {file} (expected beside the index)")
            seen.add(file)
            table[split].append((file, count))
        return table

    def split(self, name: str, meta: DatasetMeta) -> TrajectorySet:
        if name not in SPLITS:
            raise format_error(
                self.source, f"unknown split {name!r}; expected one of {list(SPLITS)}"
            )
        where = f"{self.source}: split {name!r}"
        try:
            group = self.file.get(name)
            if not isinstance(group, h5py.Group):
                raise format_error(self.source, f"missing group {name!r}")
            arrays = self._datasets(group, meta, where)
            count = group.attrs.get("count")
        except OSError as err:
            broken = self._broken_shard(name) if self.shards else None
            shard = f"shard {broken}: " if broken else ""
            raise format_error(where, f"{shard}corrupt or truncated data ({_short(err)})") from None
        matrices = {name: arrays.pop(name) for name in MATRIX_FIELDS if name in arrays}
        n, steps, agents = arrays["states"].shape[:3]
        for field_name, neutral in NEUTRAL_VALUES.items():  # absent optional data: neutral
            if field_name not in arrays:
                dtype, shape = FIELDS[field_name]
                sizes = {"n": n, "T": steps, "N": agents, "A": len(meta.action_names)}
                full = tuple(sizes.get(s, s) for s in shape)
                arrays[field_name] = np.full(full, neutral, dtype=dtype)
        if meta.schema_version == 1:
            arrays["focal"] = legacy_focal(n, agents)
        data = TrajectorySet(**arrays, **matrices)
        data.validate(meta, source=where)
        if not isinstance(count, (int, np.integer)) or int(count) != data.n:
            shown = count.item() if isinstance(count, np.generic) else count
            raise format_error(
                where, f"attribute count={shown!r} does not match {data.n} trajectories"
            )
        return data

    def _datasets(self, group: h5py.Group, meta: DatasetMeta, where: str) -> dict:
        """The split's stored datasets (required ones and those `meta` lists as recorded)."""
        stored = [f for f in FIELDS if f not in NEUTRAL_VALUES or meta.has(f)]
        if meta.schema_version == 1:
            stored.remove("focal")
        else:
            extra = [
                f
                for f in (*OPTIONAL_FIELDS, *MATRIX_FIELDS)
                if f not in stored and not meta.has(f) and f in group
            ]
            if extra:
                raise format_error(
                    where, f"holds {extra} that the root attribute 'recorded' leaves out"
                )
        datasets = {}
        for field_name in stored:
            dtype = FIELDS[field_name][0]
            dataset = group.get(field_name)
            if not isinstance(dataset, h5py.Dataset):
                raise format_error(where, f"missing dataset {field_name!r}")
            if dataset.dtype != dtype:  # check before loading: no silent casts
                raise format_error(
                    where, f"{field_name} has dtype {dataset.dtype}, expected {dtype}"
                )
            if dataset.ndim != len(FIELDS[field_name][1]):
                raise format_error(where, f"{field_name} has shape {dataset.shape}")
            datasets[field_name] = dataset
        matrix_fields = {
            INFLUENCE: (INFLUENCE_FIELD, len(INFLUENCE_KINDS)),
            INFLUENCE_WINDOWS: (INFLUENCE_WINDOWS_FIELD, meta.num_influence_windows),
        }
        for name, ((dtype, shape), size) in matrix_fields.items():
            if not meta.has(name):
                continue
            dataset = group.get(name)
            if not isinstance(dataset, h5py.Dataset):
                raise format_error(where, f"missing dataset {name!r}")
            if dataset.dtype != dtype or dataset.ndim != len(shape):
                raise format_error(
                    where,
                    f"{name} is {dataset.dtype} {dataset.shape}, expected {dtype} "
                    f"(n, {size}, N, N)",
                )
            datasets[name] = dataset
        if self.shards is not None:
            datasets = self._mapped(group, datasets, where)
        return {field_name: dataset[()] for field_name, dataset in datasets.items()}

    def _mapped(self, group: h5py.Group, datasets: dict, where: str) -> dict:
        """An index's split datasets, checked to map exactly its listed shards, each of which is
        checked to hold those rows (HDF5 would read a missing source as zeros), and opened so that
        the shards are looked for beside the index first."""
        split = group.name.strip("/")
        listed = self.shards[split]
        access = h5py.h5p.create(h5py.h5p.DATASET_ACCESS)
        access.set_virtual_prefix(os.fsencode(self.path.parent.absolute()) + b"/")
        opened = {}
        for field_name, dataset in datasets.items():
            files = [s.file_name for s in dataset.virtual_sources()] if dataset.is_virtual else []
            if files != [file for file, _ in listed]:
                raise format_error(
                    where, f"{field_name} does not map the shards listed in 'shards'"
                )
            if dataset.shape[0] != sum(count for _, count in listed):
                raise format_error(
                    where, f"{field_name} has {dataset.shape[0]} rows, unlike its shards"
                )
            opened[field_name] = h5py.Dataset(
                h5py.h5d.open(group.id, field_name.encode(), dapl=access)
            )
        for position, (file, count) in enumerate(listed):
            self._check_shard(file, position, count, split, datasets)
        return opened

    def _check_shard(
        self, file: str, position: int, count: int, split: str, datasets: dict
    ) -> None:
        """The shard is this dataset's block `position` of `split` (its `config` says so, and
        its description matches the index's: a swapped or foreign shard of the same shape is
        refused) and holds `count` rows of each of `split`'s datasets, as the index maps them."""
        where = f"{self.source}: shard {file}"
        try:
            with h5py.File(self.path.parent / file, "r") as shard:
                attrs = dict(shard.attrs)
                try:
                    label = json.loads(attrs.get("config", "{}")).get("shard")
                except (TypeError, ValueError, AttributeError):
                    label = None
                if label != {"split": split, "index": position}:
                    raise format_error(
                        where, f"is not block {position} of {split} (its config: {label})"
                    )
                for name in _SHARD_SHARED_ATTRS:
                    if not _same_attr(attrs.get(name), self.file.attrs.get(name)):
                        raise format_error(
                            where, f"root attribute {name!r} differs from the index's"
                        )
                for field_name, mapped in datasets.items():
                    source = shard.get(f"{split}/{field_name}")
                    if not isinstance(source, h5py.Dataset):
                        raise format_error(where, f"missing dataset {split}/{field_name}")
                    expected = (count, *mapped.shape[1:])
                    if source.dtype != mapped.dtype or source.shape != expected:
                        raise format_error(
                            where,
                            f"{split}/{field_name} is {source.dtype} {source.shape}, "
                            f"the index maps {mapped.dtype} {expected}",
                        )
        except OSError as err:
            raise format_error(where, f"not a readable HDF5 file ({_short(err)})") from None

    def _broken_shard(self, split: str) -> str | None:
        """The first shard of `split` whose data cannot be read alone (after a read error)."""
        for file, _ in self.shards[split]:
            try:
                with h5py.File(self.path.parent / file, "r") as shard:
                    for dataset in shard[split].values():
                        _ = dataset[()]
            except (OSError, KeyError):
                return file
        return None

    def _text(self, attrs: dict, name: str) -> str:
        value = attrs[name]
        if isinstance(value, bytes):
            value = value.decode("utf-8", errors="replace")
        if not isinstance(value, str):
            raise format_error(self.source, f"attribute {name!r} must be a string, got {value!r}")
        return value

    def _number(self, attrs: dict, name: str, kind: type) -> int | float:
        value = attrs[name]
        if np.ndim(value) != 0 or isinstance(value, (str, bytes, bool, np.bool_)):
            raise format_error(self.source, f"attribute {name!r} must be a number, got {value!r}")
        if kind is int and not isinstance(value, (int, np.integer)):
            raise format_error(self.source, f"attribute {name!r} must be an integer, got {value!r}")
        return kind(value)

    def _json(self, attrs: dict, name: str, kind: type) -> list | dict:
        try:
            value = json.loads(self._text(attrs, name))
        except json.JSONDecodeError:
            raise format_error(self.source, f"attribute {name!r} is not valid JSON") from None
        if not isinstance(value, kind):
            raise format_error(self.source, f"attribute {name!r} must be a JSON {kind.__name__}")
        return value


# root attributes a shard shares with its index (its config adds "shard"; the index's adds
# the whole run's totals)
_SHARD_SHARED_ATTRS = tuple(a for a in ROOT_ATTRS if a not in ("schema_version", "config"))


def _same_attr(a: object, b: object) -> bool:
    """Equal HDF5 attribute values (numpy scalars and strings alike)."""
    return a is not None and b is not None and bool(np.all(np.asarray(a) == np.asarray(b)))


def _short(err: BaseException) -> str:
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def read_meta(path: str | os.PathLike) -> DatasetMeta:
    """The file's metadata (root attributes), validated."""
    with _Reader(path) as reader:
        return reader.meta()


def read_split(path: str | os.PathLike, split: str) -> TrajectorySet:
    """One split of the file, validated against the file's metadata."""
    with _Reader(path) as reader:
        return reader.split(split, reader.meta())


def read_dataset(path: str | os.PathLike) -> tuple[DatasetMeta, dict[str, TrajectorySet]]:
    """Metadata and all three splits, validated."""
    with _Reader(path) as reader:
        meta = reader.meta()
        return meta, {name: reader.split(name, meta) for name in SPLITS}


def shard_files(path: str | os.PathLike) -> list[Path]:
    """The shard files of an index (schema 3), in split and row order; [] for a single file.

    Checks that each is present (as every read does), not what it holds."""
    with _Reader(path) as reader:
        reader.meta()
        if reader.shards is None:
            return []
        return [reader.path.parent / file for s in SPLITS for file, _ in reader.shards[s]]


def summarize(path: str | os.PathLike) -> str:
    """Human-readable multi-line summary of a valid file (reads and validates all of it)."""
    meta, splits = read_dataset(path)
    shards = shard_files(path)
    size_mb = sum(p.stat().st_size for p in [Path(path), *shards]) / 1e6
    where = f"index of {len(shards)} shards, " if shards else ""
    steps = meta.num_steps
    agents = sorted({s.num_agents for s in splits.values()})
    cases = list(meta.case_names)
    lines = [
        f"file:      {path} ({where}{size_mb:.2f} MB)",
        f"format:    {FORMAT_NAME} schema v{meta.schema_version}, "
        f"written by package {meta.package_version}",
        f"scenario:  {meta.scenario}",
        f"steps:     T={steps} (observed {meta.num_observed} + predicted {meta.num_predicted}), "
        f"dt={meta.dt:g} s, {steps * meta.dt:g} s per trajectory",
        f"agents:    N={'/'.join(str(a) for a in agents)} slots; "
        f"roles: {', '.join(meta.role_names)}",
        f"cases:     {', '.join(cases)}"
        + (f" (major: {meta.major_case})" if meta.major_case else ""),
        f"states:    {', '.join(meta.state_names)}; actions: "
        f"{', '.join(meta.action_names) or 'none'}",
        f"recorded:  {', '.join(meta.recorded) or 'none'} "
        f"(of the optional {', '.join(RECORDABLE)})",
        "",
        "split   "
        + "".join(f"{c:>10}" for c in [*cases, "total"])
        + "   valid agents/step   focal/window",
    ]
    for name, data in splits.items():
        counts = [int((data.case == i).sum()) for i in range(len(cases))] + [data.n]
        mean_valid = f"{data.valid.sum(axis=2).mean():.2f}" if data.n else "-"
        mean_focal = f"{data.focal.sum(axis=1).mean():.2f}" if data.n else "-"
        lines.append(
            f"{name:<8}"
            + "".join(f"{c:>10}" for c in counts)
            + f"   {mean_valid:>17}   {mean_focal:>12}"
        )
    if meta.has(INFLUENCE):
        lines += ["", *influence_lines(meta, splits)]
    if meta.has(INFLUENCE_WINDOWS):
        lines += ["", *influence_window_lines(meta, splits)]
    return "\n".join(lines)


def influence_rows(meta: DatasetMeta, splits: dict[str, TrajectorySet]) -> list[dict]:
    """The labelled agents' influence against the others', over all splits: one row per kind
    (INFLUENCE_KINDS), case and role of the attending agent i, pooling every window where i
    attends to j (an attention label at any step): `pairs`, `labelled` (mean influence[i, j]
    [m]), `strongest_other` (mean over windows of the largest influence[i, k] of any other agent
    k, not i or j) and `share_above` (share of windows where influence[i, j] exceeds every
    other's). Requires recorded influence and attention labels."""
    if not (meta.has(INFLUENCE) and meta.has("attention")):
        raise ValueError("the influence summary needs recorded influence and attention labels")
    pooled: dict[tuple[int, int, int], list[tuple[float, float]]] = {}
    for data in splits.values():
        agents = np.arange(data.num_agents)
        for window in range(data.n):
            labels = data.attention[window]  # (T, N)
            for i, j in _pairs(labels):
                others = (agents != i) & (agents != j)
                for kind in range(len(INFLUENCE_KINDS)):
                    row = data.influence[window, kind, i]  # (N,) influence of each agent on i
                    strongest = float(np.nanmax(row[others], initial=0.0))
                    key = (kind, int(data.case[window]), int(data.roles[window, i]))
                    pooled.setdefault(key, []).append((float(row[j]), strongest))
    rows = []
    for (kind, case, role), values in sorted(pooled.items()):
        labelled, strongest = np.array(values).T
        rows.append(
            {
                "kind": INFLUENCE_KINDS[kind],
                "case": meta.case_names[case],
                "role": meta.role_names[role],
                "pairs": len(values),
                "labelled": float(np.nanmean(labelled)),
                "strongest_other": float(np.nanmean(strongest)),
                "share_above": float(np.mean(labelled > strongest)),
            }
        )
    return rows


def _pairs(labels: np.ndarray) -> list[tuple[int, int]]:
    """(attending agent, labelled agent) pairs of one window's labels (T, N), in order."""
    steps, agents = np.nonzero(labels >= 0)
    return sorted({(int(i), int(labels[t, i])) for t, i in zip(steps, agents)})


def influence_lines(meta: DatasetMeta, splits: dict[str, TrajectorySet]) -> list[str]:
    """`influence_rows` as the summary's table (or one line saying why there is none)."""
    if not meta.has("attention"):
        return ["influence: recorded (no attention labels to compare it with)"]
    rows = influence_rows(meta, splits)
    lines = [
        "influence of the labelled agent on the attending one (ADE over the predicted steps "
        "when removed) [m]:",
        f"{'removed for':<12}{'case':<10}{'attending':<14}{'windows':>8}{'labelled':>10}"
        f"{'max other':>11}{'labelled > all others':>23}",
    ]
    for row in rows:
        lines.append(
            f"{row['kind']:<12}{row['case']:<10}{row['role']:<14}{row['pairs']:>8}"
            f"{row['labelled']:>10.3f}{row['strongest_other']:>11.3f}"
            f"{100 * row['share_above']:>22.1f}%"
        )
    return lines
