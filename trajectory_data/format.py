"""Trajectory dataset format, schema v2: the contract (names, fields, versions), the in-memory
`DatasetMeta` and `TrajectorySet` with their validation, and the writer. Reading (schema 1 and 2
files, schema-3 indexes of shards) is `trajectory_data.reader`.

The written contract is docs/dataset_format.md. One HDF5 file holds one scenario (or one real
data set), split into `train`, `val` and `test`; each split is a `TrajectorySet` of time-major
arrays `(n, T, N, F)`. Everything that reads or writes trajectories goes through these two
modules, so any data source that can fill a `TrajectorySet` can feed the predictor. Every read
validates and raises `FormatError` with one line naming the file and the problem. h5py and
numpy only.

Schema 2 requires only positions (`x`, `y` as the first state channels), validity and the
per-window `focal` mask (the agents that are scored and select checkpoints). The other datasets
(`OPTIONAL_FIELDS`) are optional: `DatasetMeta.recorded` names those a file holds, and in memory
an absent one is filled with its neutral value (`NEUTRAL_VALUES`: no action channels' values,
no attention label, no interaction period, case 0, seed -1, role 0), so every consumer sees the
same arrays whatever the source recorded. Code that needs real labels or states checks
`DatasetMeta.recorded` / `DatasetMeta.state_names` and fails with one line where they are absent.
A schema-1 file reads as schema 2 with everything recorded and the first two agent slots focal
(`legacy_focal`), which is what the metrics of schema 1 scored.

Schema 4 is schema 2 plus the optional per-split datasets `influence` (counterfactual ground
truth, `INFLUENCE_KINDS`) and `influence_windows` (the same per predicted-time window of
`DatasetMeta.influence_window_steps` steps, the root attribute of that name), listed in
`recorded` where a file holds them. A writer writes the lowest schema that describes the file
(`written_schema`): 2 without either, so such files keep their bytes and older readers read
them, 4 with one, which older readers refuse by its number (or, schema-4 readers that predate
`influence_windows`, by the unknown name in `recorded`) instead of misreading. In memory an
absent one is None, never filled.

Schema 3 is the index of a sharded dataset (written by `trajectory_data.shards`): a schema-2
file whose split datasets are HDF5 virtual datasets over shard files beside it, listed in the root
attribute `shards`. It reads like one file; the reader first checks that every listed shard is there
and holds the rows, dtypes and shapes the index maps (HDF5 itself would read a missing shard as
zeros) and fails with one line naming the shard otherwise.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from trajectory_data import __version__

FORMAT_NAME = "smooth-attention-trajectories"
SCHEMA_VERSION = 2  # what `write_dataset` writes (a single file, or one shard) without influence
INDEX_SCHEMA_VERSION = 3  # an index of shards (`trajectory_data.shards`): schema 2 plus `shards`
INFLUENCE_SCHEMA_VERSION = 4  # schema 2 plus the optional dataset `influence`
SUPPORTED_VERSIONS = (1, 2, 3, 4)  # what the reader reads
SPLITS = ("train", "val", "test")
STATE_NAMES = ("x", "y", "heading", "speed")  # the synthetic scenarios' (and schema 1's) states
ACTION_NAMES = ("steering", "acceleration")  # the synthetic scenarios' (and schema 1's) actions
REQUIRED_STATES = ("x", "y")  # the first state channels of every file [m]
LEGACY_FOCAL_AGENTS = 2  # schema 1: the first two agent slots are the scored (main) agents

# Per-split datasets: name -> (dtype, shape with "n", "T", "N", "C" (state channels) and "A"
# (action channels) placeholders), in contract order.
FIELDS: dict[str, tuple[np.dtype, tuple[str | int, ...]]] = {
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
# Counterfactual ground truth (schema 4), per split: influence[k, kind, i, j] [m], the average
# displacement of agent i over the predicted steps when agent j is removed, for the whole
# episode (kind 0) or from the first predicted step on (kind 1); 0 on the diagonal, NaN where
# agent i is absent (docs/dataset_format.md). Never filled when absent (it is N x N per window).
INFLUENCE = "influence"
INFLUENCE_KINDS = ("episode", "predicted")
INFLUENCE_FIELD = (np.dtype(np.float32), ("n", len(INFLUENCE_KINDS), "N", "N"))
# Per predicted-time window (schema 4), per split: influence_windows[k, w, i, j] [m], the ADE of
# agent i over the steps of window w when agent j is removed from the window's first step on;
# window w holds the steps num_observed + w L .. num_observed + (w + 1) L - 1 (the last one cut
# at T), L = DatasetMeta.influence_window_steps, W = ceil(num_predicted / L) windows.
INFLUENCE_WINDOWS = "influence_windows"
INFLUENCE_WINDOWS_FIELD = (np.dtype(np.float32), ("n", "W", "N", "N"))
INFLUENCE_WINDOW_ATTR = "influence_window_steps"  # root attribute, only in files that hold them
MATRIX_FIELDS = (INFLUENCE, INFLUENCE_WINDOWS)  # (n, K, N, N) per scene, None when absent
RECORDABLE = (*OPTIONAL_FIELDS, *MATRIX_FIELDS)  # what `recorded` may list
_AGENT_AXIS = {"states": 2, "actions": 2, "valid": 2, "focal": 1, "attention": 2, "roles": 1}
ROOT_ATTRS_V1 = (
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
ROOT_ATTRS = (*ROOT_ATTRS_V1, "recorded")  # schema 2
ROOT_ATTRS_V3 = (*ROOT_ATTRS, "shards")  # schema 3: an index of shards


class FormatError(ValueError):
    """A dataset file or array set does not follow the format; the message is one line."""


def format_error(source: str, what: str) -> FormatError:
    """Build a one-line FormatError naming the source (file or object) and the problem."""
    where = f"{source}: " if source else ""
    return FormatError(f"{where}{what}".replace("\n", " "))


@dataclass(frozen=True)
class DatasetMeta:
    """File-level description shared by all splits (root attributes of the file)."""

    scenario: str  # scenario version, e.g. "halting_car_v3" (older files: "halting_car" = v0)
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
    # optional datasets (RECORDABLE) the file holds; absent OPTIONAL_FIELDS read as
    # NEUTRAL_VALUES, an absent influence as None
    recorded: tuple[str, ...] = OPTIONAL_FIELDS
    # steps per window of influence_windows (>= 1) where recorded lists it, else 0
    influence_window_steps: int = 0

    def __post_init__(self) -> None:
        for name in ("case_names", "role_names", "state_names", "action_names", "recorded"):
            object.__setattr__(self, name, tuple(getattr(self, name)))

    def has(self, name: str) -> bool:
        """Whether the optional dataset `name` (one of RECORDABLE) holds recorded data."""
        return name in self.recorded

    def state_index(self, name: str) -> int | None:
        """Channel of state `name` in `states`, None if the file has no such channel."""
        return self.state_names.index(name) if name in self.state_names else None

    @property
    def num_steps(self) -> int:
        """Recorded steps per trajectory, T = num_observed + num_predicted."""
        return self.num_observed + self.num_predicted

    @property
    def num_influence_windows(self) -> int:
        """W = ceil(num_predicted / influence_window_steps) windows of influence_windows (0
        where the file records none)."""
        if not self.has(INFLUENCE_WINDOWS):
            return 0
        return -(-self.num_predicted // self.influence_window_steps)

    def validate(self, source: str = "") -> None:
        """Raise FormatError if a field is out of its documented range."""
        if self.schema_version not in SUPPORTED_VERSIONS:
            raise format_error(
                source,
                f"schema_version is {self.schema_version!r}, this reader "
                f"supports {versions_text()}",
            )
        if not isinstance(self.scenario, str) or not self.scenario:
            raise format_error(source, "scenario must be a non-empty string")
        if not (
            isinstance(self.dt, (int, float, np.floating))
            and math.isfinite(self.dt)
            and self.dt > 0
        ):
            raise format_error(
                source, f"dt must be a positive finite number of seconds, got {self.dt!r}"
            )
        for name in ("num_observed", "num_predicted"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 0:
                raise format_error(source, f"{name} must be a non-negative integer, got {value!r}")
        for name in ("case_names", "role_names"):
            names = getattr(self, name)
            if not names or not all(isinstance(s, str) and s for s in names):
                raise format_error(source, f"{name} must be a non-empty list of non-empty strings")
            if len(set(names)) != len(names):
                raise format_error(source, f"{name} has duplicates: {list(names)}")
        if self.major_case and self.major_case not in self.case_names:
            raise format_error(
                source, f"major_case {self.major_case!r} is not one of {list(self.case_names)}"
            )
        self._validate_channels(source)
        try:
            json.dumps(self.config, allow_nan=False)
        except (TypeError, ValueError) as err:
            raise format_error(source, f"config is not JSON-serialisable: {err}") from None

    def _validate_channels(self, source: str) -> None:
        for name in ("state_names", "action_names", "recorded"):
            names = getattr(self, name)
            if not all(isinstance(s, str) and s for s in names):
                raise format_error(source, f"{name} must be a list of non-empty strings")
            if len(set(names)) != len(names):
                raise format_error(source, f"{name} has duplicates: {list(names)}")
        if self.state_names[:2] != REQUIRED_STATES:
            raise format_error(
                source,
                f"state_names must start with {list(REQUIRED_STATES)}, "
                f"got {list(self.state_names)}",
            )
        unknown = [name for name in self.recorded if name not in RECORDABLE]
        if unknown:
            raise format_error(
                source, f"recorded names unknown datasets {unknown}; optional are {RECORDABLE}"
            )
        for name in MATRIX_FIELDS:
            if self.has(name) and self.schema_version in (1, 3):
                raise format_error(
                    source,
                    f"{name} needs schema {INFLUENCE_SCHEMA_VERSION}, not schema "
                    f"{self.schema_version}",
                )
        steps = self.influence_window_steps
        if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool):
            raise format_error(source, f"{INFLUENCE_WINDOW_ATTR} must be an integer, got {steps!r}")
        if self.has(INFLUENCE_WINDOWS) != (steps >= 1) or steps < 0:
            raise format_error(
                source,
                f"{INFLUENCE_WINDOW_ATTR} must be >= 1 where recorded lists "
                f"{INFLUENCE_WINDOWS}, else 0; got {steps}",
            )


def written_schema(meta: DatasetMeta) -> int:
    """The schema a file of `meta` is written as: INFLUENCE_SCHEMA_VERSION if it records
    influence (either MATRIX_FIELDS), else SCHEMA_VERSION (so files without keep their bytes)."""
    recorded = any(meta.has(name) for name in MATRIX_FIELDS)
    return INFLUENCE_SCHEMA_VERSION if recorded else SCHEMA_VERSION


def versions_text() -> str:
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
    influence: np.ndarray | None = None  # (n, 2, N, N) float32 [m] (schema 4), None: absent
    influence_windows: np.ndarray | None = None  # (n, W, N, N) float32 [m] (schema 4), None: absent

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
        return {name: getattr(self, name) for name in FIELDS}

    def validate(self, meta: DatasetMeta | None = None, source: str = "") -> None:
        """Raise FormatError unless dtypes, shapes and values follow the contract.

        With `meta`, also checks T against num_observed + num_predicted, the state and action
        channels against their names, the case and role indices against the names, and that
        the optional datasets `meta` does not list as recorded hold their neutral values.
        """
        self._check_shapes(source)
        n, agents = self.n, self.num_agents
        if self.states.shape[3] < len(REQUIRED_STATES):
            raise format_error(source, f"states need at least the channels {list(REQUIRED_STATES)}")
        if meta is not None:
            self._check_meta(meta, source)
        self._check_influence(source, None if meta is None else meta.num_influence_windows)
        if n == 0:
            return
        if not np.isfinite(self.states[self.valid]).all():
            raise format_error(source, "states are not finite where valid")
        bad = (self.attention < -1) | (self.attention >= agents)
        if bad.any():
            raise format_error(
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
                raise format_error(source, f"{name} has negative index {int(values.min())}")
            if limit is not None and values.size and values.max() >= limit:
                raise format_error(
                    source, f"{name} index {int(values.max())} out of range for {limit} names"
                )

    def matrices(self) -> dict[str, np.ndarray]:
        """The MATRIX_FIELDS the set holds (influence, influence_windows), by name."""
        return {
            name: getattr(self, name) for name in MATRIX_FIELDS if getattr(self, name) is not None
        }

    def _check_influence(self, source: str, num_windows: int | None = None) -> None:
        """Dtype, shape and values of the MATRIX_FIELDS held; `num_windows` (W, from the
        metadata) where known."""
        for name, matrix in self.matrices().items():
            if name == INFLUENCE:
                kinds, axis_text = len(INFLUENCE_KINDS), f"kinds {list(INFLUENCE_KINDS)}"
            else:
                kinds, axis_text = num_windows, "windows W"
            if not isinstance(matrix, np.ndarray) or matrix.dtype != np.float32:
                raise format_error(source, f"{name} must be a float32 array")
            kinds = matrix.shape[1] if kinds is None and matrix.ndim == 4 else kinds
            expected = (self.n, kinds, self.num_agents, self.num_agents)
            if matrix.shape != expected:
                raise format_error(
                    source,
                    f"{name} has shape {matrix.shape}, expected {expected} (n, {axis_text}, N, N)",
                )
            if (matrix < 0).any() or np.isinf(matrix).any():
                raise format_error(source, f"{name} must be NaN or finite and non-negative [m]")

    def _check_meta(self, meta: DatasetMeta, source: str) -> None:
        if self.num_steps != meta.num_steps:
            raise format_error(
                source,
                f"T={self.num_steps} but num_observed + num_predicted = "
                f"{meta.num_observed} + {meta.num_predicted} = {meta.num_steps}",
            )
        for name, names in (("states", meta.state_names), ("actions", meta.action_names)):
            if getattr(self, name).shape[3] != len(names):
                raise format_error(
                    source,
                    f"{name} has {getattr(self, name).shape[3]} channels but "
                    f"{name[:-1]}_names lists {len(names)}",
                )
        for name in MATRIX_FIELDS:
            if meta.has(name) != (getattr(self, name) is not None):
                state = "lists" if meta.has(name) else "does not list"
                raise format_error(
                    source,
                    f"the metadata {state} {name} as recorded but the split "
                    f"{'lacks it' if meta.has(name) else 'holds it'}",
                )
        for name, neutral in NEUTRAL_VALUES.items():
            if not meta.has(name) and (getattr(self, name) != neutral).any():
                raise format_error(
                    source,
                    f"{name} holds data but the metadata does not list it as recorded",
                )

    def _check_shapes(self, source: str) -> None:
        sizes: dict[str, int] = {}
        for name, (dtype, shape) in FIELDS.items():
            array = getattr(self, name)
            if not isinstance(array, np.ndarray):
                raise format_error(
                    source, f"{name} must be a numpy array, got {type(array).__name__}"
                )
            if array.dtype != dtype:
                raise format_error(source, f"{name} has dtype {array.dtype}, expected {dtype}")
            if array.ndim != len(shape):
                raise format_error(
                    source,
                    f"{name} has shape {array.shape}, expected "
                    f"{len(shape)} dimensions {_shape_text(shape)}",
                )
            for size, expected in zip(array.shape, shape, strict=True):
                if isinstance(expected, int):
                    if size != expected:
                        raise format_error(
                            source, f"{name} has shape {array.shape}, expected {_shape_text(shape)}"
                        )
                elif sizes.setdefault(expected, size) != size:
                    raise format_error(
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
        return TrajectorySet(
            **{k: np.array(v[indices]) for k, v in self.arrays().items()},
            **{k: np.array(v[indices]) for k, v in self.matrices().items()},
        )

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
        padded = [s.pad_agents(agents) for s in sets]
        arrays = [p.arrays() for p in padded]
        matrices = {}  # kept only where every set has one, of one shape
        for name in MATRIX_FIELDS:
            held = [getattr(p, name) for p in padded]
            if all(m is not None for m in held) and len({m.shape[1:] for m in held}) == 1:
                matrices[name] = np.concatenate(held)
        return TrajectorySet(
            **{k: np.concatenate([a[k] for a in arrays]) for k in FIELDS}, **matrices
        )

    def pad_agents(self, num_agents: int) -> TrajectorySet:
        """The set with its agent axis padded to `num_agents` slots (as in `concatenate`;
        influence rows and columns of padded slots are NaN)."""
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
        widths = [(0, 0), (0, 0), (0, extra), (0, extra)]  # absent agents: NaN rows and columns
        matrices = {
            k: np.pad(v, widths, constant_values=np.nan) for k, v in self.matrices().items()
        }
        return TrajectorySet(**out, **matrices)

    @staticmethod
    def empty(
        num_steps: int,
        num_agents: int,
        num_states: int = len(STATE_NAMES),
        num_actions: int = len(ACTION_NAMES),
    ) -> TrajectorySet:
        """A set of zero trajectories with the given T, N and state and action channels (no
        influence)."""
        sizes = {"n": 0, "T": num_steps, "N": num_agents, "C": num_states, "A": num_actions}
        return TrajectorySet(
            **{
                name: np.zeros(tuple(sizes.get(s, s) for s in shape), dtype=dtype)
                for name, (dtype, shape) in FIELDS.items()
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
    empty = TrajectorySet.empty(meta.num_steps, agents, *channels)
    sizes = {INFLUENCE: len(INFLUENCE_KINDS), INFLUENCE_WINDOWS: meta.num_influence_windows}
    empty = dataclasses.replace(
        empty,
        **{
            name: np.zeros((0, size, agents, agents), dtype=np.float32)
            for name, size in sizes.items()
            if meta.has(name)
        },
    )
    full = {s: splits.get(s, empty) for s in SPLITS}
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
    attrs["schema_version"] = np.int64(written_schema(meta))
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
    if meta.has(INFLUENCE_WINDOWS):  # only here, so that other files keep their bytes
        attrs[INFLUENCE_WINDOW_ATTR] = np.int64(meta.influence_window_steps)


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
    for name, matrix in data.matrices().items():
        if name not in recorded:
            continue
        if data.n > 0:
            group.create_dataset(
                name,
                data=matrix,
                chunks=(1, *matrix.shape[1:]),
                compression="gzip",
                compression_opts=4,
                shuffle=True,
            )
        else:
            group.create_dataset(name, data=matrix)
