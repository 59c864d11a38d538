"""Trajectory dataset format, schema v2 (reads v1, and v3 indexes of shards): reader, writer and
validation.

The written contract is docs/dataset_format.md. One HDF5 file holds one scenario (or one real
data set), split into `train`, `val` and `test`; each split is a `TrajectorySet` of time-major
arrays `(n, T, N, F)`. Everything that reads or writes trajectories goes through this module, so
any data source that can fill a `TrajectorySet` can feed the predictor. Every read validates and
raises `FormatError` with one line naming the file and the problem. h5py and numpy only.

Schema 2 requires only positions (`x`, `y` as the first state channels), validity and the
per-window `focal` mask (the agents that are scored and select checkpoints). The other datasets
(`OPTIONAL_FIELDS`) are optional: `DatasetMeta.recorded` names those a file holds, and in memory
an absent one is filled with its neutral value (`NEUTRAL_VALUES`: no action channels' values,
no attention label, no interaction period, case 0, seed -1, role 0), so every consumer sees the
same arrays whatever the source recorded. Code that needs real labels or states checks
`DatasetMeta.recorded` / `DatasetMeta.state_names` and fails with one line where they are absent.
A schema-1 file reads as schema 2 with everything recorded and the first two agent slots focal
(`legacy_focal`), which is what the metrics of schema 1 scored.

Schema 3 is the index of a sharded dataset (written by `predictor.shards`): a schema-2 file whose
split datasets are HDF5 virtual datasets over shard files beside it, listed in the root attribute
`shards`. It reads like one file; the reader first checks that every listed shard is there and
holds the rows, dtypes and shapes the index maps (HDF5 itself would read a missing shard as
zeros) and fails with one line naming the shard otherwise.
"""

from __future__ import annotations

import json
import math
import os
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from predictor import __version__

FORMAT_NAME = "smooth-attention-trajectories"
SCHEMA_VERSION = 2  # what `write_dataset` writes (a single file, or one shard)
INDEX_SCHEMA_VERSION = 3  # an index of shards (`predictor.shards`): schema 2 plus `shards`
SUPPORTED_VERSIONS = (1, 2, 3)  # what the reader reads
SPLITS = ("train", "val", "test")
STATE_NAMES = ("x", "y", "heading", "speed")  # the synthetic scenarios' (and schema 1's) states
ACTION_NAMES = ("steering", "acceleration")  # the synthetic scenarios' (and schema 1's) actions
REQUIRED_STATES = ("x", "y")  # the first state channels of every file [m]
LEGACY_FOCAL_AGENTS = 2  # schema 1: the first two agent slots are the scored (main) agents

# Per-split datasets: name -> (dtype, shape with "n", "T", "N", "C" (state channels) and "A"
# (action channels) placeholders), in contract order.
_FIELDS: dict[str, tuple[np.dtype, tuple[str | int, ...]]] = {
    "states": (np.dtype(np.float32), ("n", "T", "N", "C")),
    "actions": (np.dtype(np.float32), ("n", "T", "N", "A")),
    "valid": (np.dtype(np.bool_), ("n", "T", "N")),
    "focal": (np.dtype(np.bool_), ("n", "N")),
    "attention": (np.dtype(np.int16), ("n", "T", "N")),
    "interaction": (np.dtype(np.bool_), ("n", "T")),
    "case": (np.dtype(np.int8), ("n",)),
    "seed": (np.dtype(np.int64), ("n",)),
    "roles": (np.dtype(np.int8), ("n", "N")),
}
# Optional datasets (schema 2) and the value an absent one is filled with in memory.
NEUTRAL_VALUES: dict[str, int | bool] = {
    "actions": 0,
    "attention": -1,
    "interaction": False,
    "case": 0,
    "seed": -1,
    "roles": 0,
}
OPTIONAL_FIELDS = tuple(NEUTRAL_VALUES)
_AGENT_AXIS = {"states": 2, "actions": 2, "valid": 2, "focal": 1, "attention": 2, "roles": 1}
_ROOT_ATTRS_V1 = (
    "format",
    "schema_version",
    "scenario",
    "dt",
    "num_observed",
    "num_predicted",
    "case_names",
    "major_case",
    "role_names",
    "state_names",
    "action_names",
    "config",
    "package_version",
)
_ROOT_ATTRS = (*_ROOT_ATTRS_V1, "recorded")  # schema 2
_ROOT_ATTRS_V3 = (*_ROOT_ATTRS, "shards")  # schema 3: an index of shards


class FormatError(ValueError):
    """A dataset file or array set does not follow the format; the message is one line."""


def _fail(source: str, what: str) -> FormatError:
    """Build a one-line FormatError naming the source (file or object) and the problem."""
    where = f"{source}: " if source else ""
    return FormatError(f"{where}{what}".replace("\n", " "))


@dataclass(frozen=True)
class DatasetMeta:
    """File-level description shared by all splits (root attributes of the file)."""

    scenario: str  # scenario name, e.g. "double_merge"
    dt: float  # seconds between two recorded steps [s]
    num_observed: int  # suggested number of observed (history) steps
    num_predicted: int  # suggested number of predicted steps
    case_names: tuple[str, ...]  # `case` arrays index into this
    major_case: str  # the frequent case, one of case_names, or "" if not applicable
    role_names: tuple[str, ...]  # `roles` arrays index into this
    config: dict = field(default_factory=dict)  # configuration that produced the file (JSON)
    package_version: str = __version__  # version of the package that wrote the file
    schema_version: int = SCHEMA_VERSION  # of the file read (a writer writes SCHEMA_VERSION)
    # names of the state channels, x and y first; default: the synthetic scenarios' four
    state_names: tuple[str, ...] = STATE_NAMES
    # names of the action channels (may be none); default: the synthetic scenarios' two
    action_names: tuple[str, ...] = ACTION_NAMES
    # optional datasets (OPTIONAL_FIELDS) the file holds; the others read as NEUTRAL_VALUES
    recorded: tuple[str, ...] = OPTIONAL_FIELDS

    def __post_init__(self) -> None:
        for name in ("case_names", "role_names", "state_names", "action_names", "recorded"):
            object.__setattr__(self, name, tuple(getattr(self, name)))

    def has(self, name: str) -> bool:
        """Whether the optional dataset `name` (one of OPTIONAL_FIELDS) holds recorded data."""
        return name in self.recorded

    def state_index(self, name: str) -> int | None:
        """Channel of state `name` in `states`, None if the file has no such channel."""
        return self.state_names.index(name) if name in self.state_names else None

    @property
    def num_steps(self) -> int:
        """Recorded steps per trajectory, T = num_observed + num_predicted."""
        return self.num_observed + self.num_predicted

    def validate(self, source: str = "") -> None:
        """Raise FormatError if a field is out of its documented range."""
        if self.schema_version not in SUPPORTED_VERSIONS:
            raise _fail(
                source,
                f"schema_version is {self.schema_version!r}, this reader "
                f"supports {_versions_text()}",
            )
        if not isinstance(self.scenario, str) or not self.scenario:
            raise _fail(source, "scenario must be a non-empty string")
        if not (
            isinstance(self.dt, (int, float, np.floating))
            and math.isfinite(self.dt)
            and self.dt > 0
        ):
            raise _fail(source, f"dt must be a positive finite number of seconds, got {self.dt!r}")
        for name in ("num_observed", "num_predicted"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 0:
                raise _fail(source, f"{name} must be a non-negative integer, got {value!r}")
        for name in ("case_names", "role_names"):
            names = getattr(self, name)
            if not names or not all(isinstance(s, str) and s for s in names):
                raise _fail(source, f"{name} must be a non-empty list of non-empty strings")
            if len(set(names)) != len(names):
                raise _fail(source, f"{name} has duplicates: {list(names)}")
        if self.major_case and self.major_case not in self.case_names:
            raise _fail(
                source, f"major_case {self.major_case!r} is not one of {list(self.case_names)}"
            )
        self._validate_channels(source)
        try:
            json.dumps(self.config, allow_nan=False)
        except (TypeError, ValueError) as err:
            raise _fail(source, f"config is not JSON-serialisable: {err}") from None

    def _validate_channels(self, source: str) -> None:
        for name in ("state_names", "action_names", "recorded"):
            names = getattr(self, name)
            if not all(isinstance(s, str) and s for s in names):
                raise _fail(source, f"{name} must be a list of non-empty strings")
            if len(set(names)) != len(names):
                raise _fail(source, f"{name} has duplicates: {list(names)}")
        if self.state_names[:2] != REQUIRED_STATES:
            raise _fail(
                source,
                f"state_names must start with {list(REQUIRED_STATES)}, "
                f"got {list(self.state_names)}",
            )
        unknown = [name for name in self.recorded if name not in OPTIONAL_FIELDS]
        if unknown:
            raise _fail(
                source, f"recorded names unknown datasets {unknown}; optional are {OPTIONAL_FIELDS}"
            )


def _versions_text() -> str:
    return "schema versions " + ", ".join(str(v) for v in SUPPORTED_VERSIONS)


def legacy_focal(n: int, num_agents: int) -> np.ndarray:
    """(n, N) focal mask of a schema-1 file: the first LEGACY_FOCAL_AGENTS slots."""
    focal = np.zeros((n, num_agents), dtype=bool)
    focal[:, :LEGACY_FOCAL_AGENTS] = True
    return focal


@dataclass(frozen=True, eq=False)
class TrajectorySet:
    """One split: n trajectories of T steps with N agent slots (shapes as in the contract).

    Optional datasets a source does not record hold their NEUTRAL_VALUES. `focal` left out
    (None) is the schema-1 rule, the first two slots (`legacy_focal`).
    """

    states: np.ndarray  # (n, T, N, C) float32: DatasetMeta.state_names, x [m], y [m] first
    actions: np.ndarray  # (n, T, N, A) float32: DatasetMeta.action_names
    valid: np.ndarray  # (n, T, N) bool: agent present
    attention: np.ndarray  # (n, T, N) int16: index of the attended agent, -1 for none
    interaction: np.ndarray  # (n, T) bool: inside the interaction period
    case: np.ndarray  # (n,) int8: index into case_names
    seed: np.ndarray  # (n,) int64: generating seed, -1 for foreign data
    roles: np.ndarray  # (n, N) int8: index into role_names
    focal: np.ndarray | None = None  # (n, N) bool: agents scored and selecting checkpoints

    def __post_init__(self) -> None:
        if self.focal is None and isinstance(self.states, np.ndarray) and self.states.ndim >= 3:
            object.__setattr__(
                self, "focal", legacy_focal(*self.states.shape[:1], self.states.shape[2])
            )

    @property
    def n(self) -> int:
        """Number of trajectories."""
        return int(self.states.shape[0])

    @property
    def num_steps(self) -> int:
        """Recorded steps per trajectory, T."""
        return int(self.states.shape[1])

    @property
    def num_agents(self) -> int:
        """Agent slots per trajectory, N."""
        return int(self.states.shape[2])

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays by dataset name, in contract order."""
        return {name: getattr(self, name) for name in _FIELDS}

    def validate(self, meta: DatasetMeta | None = None, source: str = "") -> None:
        """Raise FormatError unless dtypes, shapes and values follow the contract.

        With `meta`, also checks T against num_observed + num_predicted, the state and action
        channels against their names, the case and role indices against the names, and that
        the optional datasets `meta` does not list as recorded hold their neutral values.
        """
        self._check_shapes(source)
        n, agents = self.n, self.num_agents
        if self.states.shape[3] < len(REQUIRED_STATES):
            raise _fail(source, f"states need at least the channels {list(REQUIRED_STATES)}")
        if meta is not None:
            self._check_meta(meta, source)
        if n == 0:
            return
        if not np.isfinite(self.states[self.valid]).all():
            raise _fail(source, "states are not finite where valid")
        bad = (self.attention < -1) | (self.attention >= agents)
        if bad.any():
            raise _fail(
                source,
                f"attention labels must be -1 or an agent index in [0, {agents}), "
                f"found {int(self.attention[bad][0])}",
            )
        limits = {
            "case": None if meta is None else len(meta.case_names),
            "roles": None if meta is None else len(meta.role_names),
        }
        for name, limit in limits.items():
            values = getattr(self, name)
            if values.size and values.min() < 0:
                raise _fail(source, f"{name} has negative index {int(values.min())}")
            if limit is not None and values.size and values.max() >= limit:
                raise _fail(
                    source, f"{name} index {int(values.max())} out of range for {limit} names"
                )

    def _check_meta(self, meta: DatasetMeta, source: str) -> None:
        if self.num_steps != meta.num_steps:
            raise _fail(
                source,
                f"T={self.num_steps} but num_observed + num_predicted = "
                f"{meta.num_observed} + {meta.num_predicted} = {meta.num_steps}",
            )
        for name, names in (("states", meta.state_names), ("actions", meta.action_names)):
            if getattr(self, name).shape[3] != len(names):
                raise _fail(
                    source,
                    f"{name} has {getattr(self, name).shape[3]} channels but "
                    f"{name[:-1]}_names lists {len(names)}",
                )
        for name, neutral in NEUTRAL_VALUES.items():
            if not meta.has(name) and (getattr(self, name) != neutral).any():
                raise _fail(
                    source,
                    f"{name} holds data but the metadata does not list it as recorded",
                )

    def _check_shapes(self, source: str) -> None:
        sizes: dict[str, int] = {}
        for name, (dtype, shape) in _FIELDS.items():
            array = getattr(self, name)
            if not isinstance(array, np.ndarray):
                raise _fail(source, f"{name} must be a numpy array, got {type(array).__name__}")
            if array.dtype != dtype:
                raise _fail(source, f"{name} has dtype {array.dtype}, expected {dtype}")
            if array.ndim != len(shape):
                raise _fail(
                    source,
                    f"{name} has shape {array.shape}, expected "
                    f"{len(shape)} dimensions {_shape_text(shape)}",
                )
            for size, expected in zip(array.shape, shape, strict=True):
                if isinstance(expected, int):
                    if size != expected:
                        raise _fail(
                            source, f"{name} has shape {array.shape}, expected {_shape_text(shape)}"
                        )
                elif sizes.setdefault(expected, size) != size:
                    raise _fail(
                        source,
                        f"{name} has shape {array.shape}, inconsistent with "
                        f"{expected}={sizes[expected]} of states",
                    )

    def subset(self, indices: np.ndarray | Sequence[int] | slice) -> TrajectorySet:
        """Trajectories picked by integer indices, a boolean mask or a slice (copies)."""
        if not isinstance(indices, slice):
            indices = np.asarray(indices)
            if indices.dtype != np.bool_:
                indices = indices.astype(np.int64).reshape(-1)
        return TrajectorySet(**{k: np.array(v[indices]) for k, v in self.arrays().items()})

    def select_case(self, case_index: int) -> TrajectorySet:
        """Only the trajectories of one case (index into case_names)."""
        return self.subset(self.case == case_index)

    @staticmethod
    def concatenate(sets: Sequence[TrajectorySet]) -> TrajectorySet:
        """Join sets along the trajectory axis; a smaller agent axis is padded.

        Padded agent slots are invalid at every step, zero-filled, not focal, attend to nobody
        (-1) and have role 0 (meaningless, since they never appear).
        """
        if not sets:
            raise ValueError("concatenate needs at least one TrajectorySet")
        steps = {s.num_steps for s in sets}
        if len(steps) != 1:
            raise FormatError(f"cannot concatenate sets with different T: {sorted(steps)}")
        agents = max(s.num_agents for s in sets)
        padded = [s.pad_agents(agents).arrays() for s in sets]
        return TrajectorySet(**{k: np.concatenate([p[k] for p in padded]) for k in _FIELDS})

    def pad_agents(self, num_agents: int) -> TrajectorySet:
        """The set with its agent axis padded to `num_agents` slots (as in `concatenate`)."""
        extra = num_agents - self.num_agents
        if extra < 0:
            raise ValueError(f"cannot pad {self.num_agents} agent slots down to {num_agents}")
        if extra == 0:
            return self
        fill = {"attention": -1}
        out = {}
        for name, array in self.arrays().items():
            axis = _AGENT_AXIS.get(name)
            if axis is None:
                out[name] = array
                continue
            widths = [(0, 0)] * array.ndim
            widths[axis] = (0, extra)
            out[name] = np.pad(array, widths, constant_values=fill.get(name, 0))
        return TrajectorySet(**out)

    @staticmethod
    def empty(
        num_steps: int,
        num_agents: int,
        num_states: int = len(STATE_NAMES),
        num_actions: int = len(ACTION_NAMES),
    ) -> TrajectorySet:
        """A set of zero trajectories with the given T, N and state and action channels."""
        sizes = {"n": 0, "T": num_steps, "N": num_agents, "C": num_states, "A": num_actions}
        return TrajectorySet(
            **{
                name: np.zeros(tuple(sizes.get(s, s) for s in shape), dtype=dtype)
                for name, (dtype, shape) in _FIELDS.items()
            }
        )


def _shape_text(shape: tuple[str | int, ...]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ")"


# ----------------------------------------------------------------------------------------------
# Writing


def write_dataset(
    path: str | os.PathLike,
    meta: DatasetMeta,
    splits: Mapping[str, TrajectorySet],
    *,
    overwrite: bool = False,
) -> Path:
    """Validate `meta` and `splits`, then write them atomically to `path`; returns the path.

    A split left out of `splits` is written empty (same N as the first given split). The file is
    written beside the target under a temporary name and renamed at the end, so an interrupted
    write (any exception, KeyboardInterrupt included) leaves nothing at `path`.
    Raises FileExistsError if `path` exists and `overwrite` is False.
    """
    target = Path(path)
    meta.validate(source="metadata")
    unknown = sorted(set(splits) - set(SPLITS))
    if unknown:
        raise FormatError(f"unknown split names {unknown}; expected a subset of {list(SPLITS)}")
    if not splits:
        raise FormatError(f"no splits given; expected some of {list(SPLITS)}")
    agents = next(iter(splits.values())).num_agents
    channels = len(meta.state_names), len(meta.action_names)
    full = {
        s: splits.get(s, TrajectorySet.empty(meta.num_steps, agents, *channels)) for s in SPLITS
    }
    for name, data in full.items():
        data.validate(meta, source=f"split {name!r}")
    if target.exists() and not overwrite:
        raise FileExistsError(f"{target} already exists; pass overwrite=True to replace it")
    if not target.parent.is_dir():
        raise FileNotFoundError(f"output directory {target.parent} does not exist")
    temp_name = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
    try:
        with h5py.File(temp_name, "x") as file:  # "x": never clobber; permissions from umask
            _write_root_attrs(file, meta)
            for name, data in full.items():
                _write_split(file.create_group(name), data, meta.recorded)
        os.replace(temp_name, target)
    except BaseException:
        Path(temp_name).unlink(missing_ok=True)
        raise
    return target


def _write_root_attrs(file: h5py.File, meta: DatasetMeta) -> None:
    attrs = file.attrs
    attrs["format"] = FORMAT_NAME
    attrs["schema_version"] = np.int64(SCHEMA_VERSION)
    attrs["scenario"] = meta.scenario
    attrs["dt"] = np.float64(meta.dt)
    attrs["num_observed"] = np.int64(meta.num_observed)
    attrs["num_predicted"] = np.int64(meta.num_predicted)
    attrs["case_names"] = json.dumps(list(meta.case_names))
    attrs["major_case"] = meta.major_case
    attrs["role_names"] = json.dumps(list(meta.role_names))
    attrs["state_names"] = json.dumps(list(meta.state_names))
    attrs["action_names"] = json.dumps(list(meta.action_names))
    attrs["recorded"] = json.dumps(list(meta.recorded))
    attrs["config"] = json.dumps(meta.config, sort_keys=True, allow_nan=False)
    attrs["package_version"] = meta.package_version


def _write_split(group: h5py.Group, data: TrajectorySet, recorded: tuple[str, ...]) -> None:
    group.attrs["count"] = np.int64(data.n)
    for name, array in data.arrays().items():
        if name in NEUTRAL_VALUES and name not in recorded:
            continue
        if data.n > 0:  # one trajectory per chunk, gzip
            group.create_dataset(
                name,
                data=array,
                chunks=(1, *array.shape[1:]),
                compression="gzip",
                compression_opts=4,
                shuffle=True,
            )
        else:
            group.create_dataset(name, data=array)


# ----------------------------------------------------------------------------------------------
# Reading


class _Reader:
    """An open, format-checked file; converts h5py/OS errors into one-line FormatErrors."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.source = str(self.path)
        if not self.path.is_file():
            raise _fail(self.source, "no such file")
        try:
            is_hdf5 = h5py.is_hdf5(self.path)
        except OSError as err:
            raise _fail(self.source, f"cannot read file: {err}") from None
        if not is_hdf5:
            raise _fail(self.source, "not an HDF5 file")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as err:
            raise _fail(self.source, f"corrupt or truncated HDF5 file ({_short(err)})") from None
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
                    raise _fail(self.source, f"{name} must be {list(expected)}")
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
        )
        meta.validate(self.source)
        return meta

    def _root_attrs(self) -> dict:
        try:
            attrs = dict(self.file.attrs)
        except OSError as err:
            raise _fail(self.source, f"corrupt HDF5 file ({_short(err)})") from None
        if "format" not in attrs:
            raise _fail(self.source, f"not a {FORMAT_NAME} file (no 'format' attribute)")
        if self._text(attrs, "format") != FORMAT_NAME:
            raise _fail(self.source, f"format is {attrs['format']!r}, expected {FORMAT_NAME!r}")
        if "schema_version" not in attrs:
            raise _fail(self.source, "missing root attribute 'schema_version'")
        version = self._number(attrs, "schema_version", int)
        if version not in SUPPORTED_VERSIONS:
            raise _fail(
                self.source,
                f"schema_version {version} is not supported (this reader reads {_versions_text()})",
            )
        required = {1: _ROOT_ATTRS_V1, 2: _ROOT_ATTRS, 3: _ROOT_ATTRS_V3}[version]
        missing = [name for name in required if name not in attrs]
        if missing:
            raise _fail(self.source, f"missing root attribute(s) {missing}")
        return attrs

    def _shard_table(self, attrs: dict) -> dict[str, list[tuple[str, int]]]:
        """An index's root attribute `shards`, by split; every listed file must be beside it."""
        table: dict[str, list[tuple[str, int]]] = {name: [] for name in SPLITS}
        seen = set()
        for entry in self._json(attrs, "shards", list):
            if not isinstance(entry, dict) or sorted(entry) != ["count", "file", "split"]:
                raise _fail(
                    self.source, "attribute 'shards' must list {file, split, count} objects"
                )
            file, split, count = entry["file"], entry["split"], entry["count"]
            if not isinstance(file, str) or Path(file).name != file or file.startswith("."):
                raise _fail(self.source, f"shard {file!r} must be a file name beside the index")
            if split not in SPLITS or file in seen:
                raise _fail(self.source, f"shard {file} has split {split!r} or is listed twice")
            if not isinstance(count, int) or isinstance(count, bool) or count < 1:
                raise _fail(self.source, f"shard {file} has count {count!r}, expected >= 1")
            if not (self.path.parent / file).is_file():
                raise _fail(self.source, f"missing shard {file} (expected beside the index)")
            seen.add(file)
            table[split].append((file, count))
        return table

    def split(self, name: str, meta: DatasetMeta) -> TrajectorySet:
        if name not in SPLITS:
            raise _fail(self.source, f"unknown split {name!r}; expected one of {list(SPLITS)}")
        where = f"{self.source}: split {name!r}"
        try:
            group = self.file.get(name)
            if not isinstance(group, h5py.Group):
                raise _fail(self.source, f"missing group {name!r}")
            arrays = self._datasets(group, meta, where)
            count = group.attrs.get("count")
        except OSError as err:
            broken = self._broken_shard(name) if self.shards else None
            shard = f"shard {broken}: " if broken else ""
            raise _fail(where, f"{shard}corrupt or truncated data ({_short(err)})") from None
        n, steps, agents = arrays["states"].shape[:3]
        for field_name, neutral in NEUTRAL_VALUES.items():  # absent optional data: neutral
            if field_name not in arrays:
                dtype, shape = _FIELDS[field_name]
                sizes = {"n": n, "T": steps, "N": agents, "A": len(meta.action_names)}
                full = tuple(sizes.get(s, s) for s in shape)
                arrays[field_name] = np.full(full, neutral, dtype=dtype)
        if meta.schema_version == 1:
            arrays["focal"] = legacy_focal(n, agents)
        data = TrajectorySet(**arrays)
        data.validate(meta, source=where)
        if not isinstance(count, (int, np.integer)) or int(count) != data.n:
            shown = count.item() if isinstance(count, np.generic) else count
            raise _fail(where, f"attribute count={shown!r} does not match {data.n} trajectories")
        return data

    def _datasets(self, group: h5py.Group, meta: DatasetMeta, where: str) -> dict:
        """The split's stored datasets (required ones and those `meta` lists as recorded)."""
        stored = [f for f in _FIELDS if f not in NEUTRAL_VALUES or meta.has(f)]
        if meta.schema_version == 1:
            stored.remove("focal")
        else:
            extra = [f for f in OPTIONAL_FIELDS if f not in stored and f in group]
            if extra:
                raise _fail(where, f"holds {extra} that the root attribute 'recorded' leaves out")
        datasets = {}
        for field_name in stored:
            dtype = _FIELDS[field_name][0]
            dataset = group.get(field_name)
            if not isinstance(dataset, h5py.Dataset):
                raise _fail(where, f"missing dataset {field_name!r}")
            if dataset.dtype != dtype:  # check before loading: no silent casts
                raise _fail(where, f"{field_name} has dtype {dataset.dtype}, expected {dtype}")
            if dataset.ndim != len(_FIELDS[field_name][1]):
                raise _fail(where, f"{field_name} has shape {dataset.shape}")
            datasets[field_name] = dataset
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
                raise _fail(where, f"{field_name} does not map the shards listed in 'shards'")
            if dataset.shape[0] != sum(count for _, count in listed):
                raise _fail(where, f"{field_name} has {dataset.shape[0]} rows, unlike its shards")
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
                    raise _fail(where, f"is not block {position} of {split} (its config: {label})")
                for name in _SHARD_SHARED_ATTRS:
                    if not _same_attr(attrs.get(name), self.file.attrs.get(name)):
                        raise _fail(where, f"root attribute {name!r} differs from the index's")
                for field_name, mapped in datasets.items():
                    source = shard.get(f"{split}/{field_name}")
                    if not isinstance(source, h5py.Dataset):
                        raise _fail(where, f"missing dataset {split}/{field_name}")
                    expected = (count, *mapped.shape[1:])
                    if source.dtype != mapped.dtype or source.shape != expected:
                        raise _fail(
                            where,
                            f"{split}/{field_name} is {source.dtype} {source.shape}, "
                            f"the index maps {mapped.dtype} {expected}",
                        )
        except OSError as err:
            raise _fail(where, f"not a readable HDF5 file ({_short(err)})") from None

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
            raise _fail(self.source, f"attribute {name!r} must be a string, got {value!r}")
        return value

    def _number(self, attrs: dict, name: str, kind: type) -> int | float:
        value = attrs[name]
        if np.ndim(value) != 0 or isinstance(value, (str, bytes, bool, np.bool_)):
            raise _fail(self.source, f"attribute {name!r} must be a number, got {value!r}")
        if kind is int and not isinstance(value, (int, np.integer)):
            raise _fail(self.source, f"attribute {name!r} must be an integer, got {value!r}")
        return kind(value)

    def _json(self, attrs: dict, name: str, kind: type) -> list | dict:
        try:
            value = json.loads(self._text(attrs, name))
        except json.JSONDecodeError:
            raise _fail(self.source, f"attribute {name!r} is not valid JSON") from None
        if not isinstance(value, kind):
            raise _fail(self.source, f"attribute {name!r} must be a JSON {kind.__name__}")
        return value


# root attributes a shard shares with its index (its config adds "shard"; the index's adds
# the whole run's totals)
_SHARD_SHARED_ATTRS = tuple(a for a in _ROOT_ATTRS if a not in ("schema_version", "config"))


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
        f"(of the optional {', '.join(OPTIONAL_FIELDS)})",
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
    return "\n".join(lines)
