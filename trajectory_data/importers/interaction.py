"""INTERACTION track CSVs as one schema-2 file (the paper's protocol, 40 + 60 steps at 0.1 s).

Input: track files as distributed, CSV with a header naming at least `track_id, frame_id,
timestamp_ms, agent_type, x, y, vx, vy` (`case_id` optional, `psi_rad, length, width`
optional and possibly empty, as in pedestrian tracks). Frames are 0.1 s apart (the frame-id step
is derived from the data as for ETH/UCY, and the timestamps must agree with it).

Two kinds of file:
- With `case_id` (the later, segmented releases): each case is a *sequence*; the sequences are
  split 80/10/10 (never a sequence in two splits): in a seeded random order, the first
  round(0.8 S) train, the next round(0.1 S) validation, the rest test.
- Without `case_id` (the original release: one continuous recording per location,
  `<location>/vehicle_tracks_NNN.csv` plus `pedestrian_tracks_NNN.csv`, whose tracks are
  numbered P1, P2, ...): a *recording*, the vehicle and pedestrian files of one folder and
  number together (their agents share the windows, roles = agent types). Each recording is cut
  in time into contiguous blocks, train its first round(0.8 F) frame steps, validation the next
  round(0.9 F) - round(0.8 F), test the rest (F its frame steps), and a window lands in the block
  that holds all its frames; a window across a block boundary is dropped (counted in the file's
  config, about 9 per boundary at stride 10). No window shares a frame with another split's,
  which interleaved blocks could not give without dropping a window at every block's end.

The project's paper states the protocol: "For every 100 steps, we use the first 40
steps as observed steps and predict the next 60 steps ... split all sequences into 80% for
training, 10% for validation and 10% for testing".

Windows (`InteractionConfig`): 40 observed + 60 predicted steps (100 frames, 10 s) starting
every `stride` frames; every agent seen in a window is one of its agents, those present at all
100 frames are its focal agents (scored, choosing checkpoints); a window without one is dropped.
An import that would leave a split without windows is refused.

Output: states x, y [m], vx, vy [m/s], and heading [rad] (psi_rad) when every row of the input
has one; roles = the agent types (recorded); the file's config lists every sequence with its
split, frame step and window count, and (when there are any) every recording with its files,
the first and last frame id of each block, its windows per split and those dropped.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trajectory_data.format import SPLITS, DatasetMeta, TrajectorySet
from trajectory_data.importers.common import (
    MAX_ID,
    ImportDataError,
    Tracks,
    Windows,
    check_outputs,
    cut_windows,
    frame_step,
    reading_bar,
    require_splits,
    windows_set,
    write_all,
)

# vehicle_tracks_000.csv and pedestrian_tracks_000.csv of one folder: one recording (number 000)
RECORDING_FILE = re.compile(r"(vehicle|pedestrian)_tracks_(\d+)\.csv")
PEDESTRIAN_ID = re.compile(r"P\d+")
REQUIRED_COLUMNS = ("track_id", "frame_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy")
NUMBER_COLUMNS = ("x", "y", "vx", "vy")


@dataclass(frozen=True)
class InteractionConfig:
    """Protocol of the import (defaults: the paper's 40 + 60 steps at 0.1 s, 80/10/10)."""

    num_observed: int = 40  # observed steps (4 s)
    num_predicted: int = 60  # predicted steps (6 s)
    dt_s: float = 0.1  # [s] between two frames (10 Hz)
    # frames between window starts; 10 (1 s): stride 1 would repeat each 10 s stretch 100 times
    stride: int = 10
    train_fraction: float = 0.8  # of the sequences
    val_fraction: float = 0.1  # of the sequences; the rest is test
    seed: int = 0  # of the sequence order behind the split

    def __post_init__(self) -> None:
        checks = {
            "num_observed": self.num_observed >= 2,
            "num_predicted": self.num_predicted >= 1,
            "dt_s": math.isfinite(self.dt_s) and self.dt_s > 0,
            "stride": self.stride >= 1,
            "train_fraction": 0 < self.train_fraction <= 1,
            "val_fraction": 0 <= self.val_fraction <= 1 - self.train_fraction,
            "seed": self.seed >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(
                    f"InteractionConfig.{name} is out of range: {getattr(self, name)!r}"
                )

    @property
    def num_steps(self) -> int:
        """Frames per window, T."""
        return self.num_observed + self.num_predicted


@dataclass(frozen=True)
class Sequence:
    """One sequence's rows: the tracks (values x, y, vx, vy, psi_rad) and each row's type."""

    name: str  # "file" or "file#case_id"
    case: int  # the case_id; -1 for a file without that column (a continuous recording)
    tracks: Tracks
    agent_type: np.ndarray  # (R,) str
    timestamp_ms: np.ndarray  # (R,) float64


def read_sequences(path: Path) -> list[Sequence]:
    """The sequences of one track CSV; ImportDataError naming the file and line for a missing
    column, a short row, a bad number, a repeated (frame, track) or a timestamp off 0.1 s."""
    try:
        # utf-8-sig: a byte-order mark, as spreadsheet exports write, is not part of the header
        with open(path, newline="", encoding="utf-8-sig") as stream:
            reader = csv.reader(stream)
            header = [name.strip() for name in next(reader, [])]
            missing = [c for c in REQUIRED_COLUMNS if c not in header]
            if missing:
                raise ImportDataError(f"{path}:1: missing column(s) {missing} in the header")
            rows = {}  # case -> list of (line, values, type, timestamp)
            for number, fields in enumerate(reader, start=2):
                if not fields or all(not f.strip() for f in fields):
                    continue
                case, row = _parse_row(path, number, header, fields)
                rows.setdefault(case, []).append(row)
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise ImportDataError(f"{path}: cannot read ({err})") from None
    return [_sequence(path, case, part) for case, part in sorted(rows.items())]


def _parse_row(path: Path, number: int, header: list[str], fields: list[str]) -> tuple:
    where = f"{path}:{number}"
    if len(fields) != len(header):
        raise ImportDataError(f"{where}: {len(fields)} fields, the header names {len(header)}")
    cell = dict(zip(header, (f.strip() for f in fields), strict=True))

    def number_of(name: str, integral: bool = False) -> float:
        try:
            value = float(cell[name])
        except ValueError:
            raise ImportDataError(f"{where}: {name} {cell[name]!r} is not a number") from None
        if not math.isfinite(value) or (integral and not value.is_integer()):
            kind = "an integer" if integral else "a finite number"
            raise ImportDataError(f"{where}: {name} {cell[name]!r} is not {kind}")
        if integral and abs(value) >= MAX_ID:
            raise ImportDataError(f"{where}: {name} {cell[name]!r} is beyond 2**53")
        return value

    case = int(number_of("case_id", True)) if "case_id" in cell else -1
    heading = number_of("psi_rad") if cell.get("psi_rad") else math.nan
    values = [number_of(c) for c in NUMBER_COLUMNS] + [heading]
    offset = 0  # pedestrian files as shipped number their tracks P1, P2, ...: ids from MAX_ID on
    if case < 0 and PEDESTRIAN_ID.fullmatch(cell["track_id"]):
        cell["track_id"], offset = cell["track_id"][1:], MAX_ID
    ids = (int(number_of("frame_id", True)), int(number_of("track_id", True)) + offset)
    if not cell["agent_type"]:
        raise ImportDataError(f"{where}: empty agent_type")
    return case, (number, ids, values, cell["agent_type"], number_of("timestamp_ms"))


def _sequence(path: Path, case: int, rows: list[tuple]) -> Sequence:
    name = str(path) if case < 0 else f"{path}#{case}"
    ids = np.array([r[1] for r in rows], dtype=np.int64)  # (R, 2) frame, track
    tracks = Tracks(
        source=str(path),
        line=np.array([r[0] for r in rows], dtype=np.int64),
        frame=ids[:, 0],
        agent=ids[:, 1],
        values=np.array([r[2] for r in rows], dtype=np.float64),
    )
    _, first, counts = np.unique(ids, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        frame, track = ids[first[counts > 1][0]]
        again = np.flatnonzero((ids[:, 0] == frame) & (ids[:, 1] == track))[1]
        raise ImportDataError(
            f"{path}:{tracks.line[again]}: track {_track_name(track)} appears twice in frame "
            f"{frame}"
        )
    return Sequence(
        name=name,
        case=case,
        tracks=tracks,
        agent_type=np.array([r[3] for r in rows]),
        timestamp_ms=np.array([r[4] for r in rows]),
    )


def _track_name(track: int) -> str:
    """A track id as the file spells it (P-numbered pedestrians from MAX_ID on)."""
    return f"P{track - MAX_ID}" if track >= MAX_ID else str(track)


def _check_timing(sequence: Sequence, dt_s: float) -> int:
    """The frame step; ImportDataError unless the timestamps advance dt_s per step."""
    tracks = sequence.tracks
    step = frame_step(tracks)
    if step == 0:
        return 0
    expected = (tracks.frame - tracks.frame.min()) / step * dt_s * 1000.0
    offset = sequence.timestamp_ms - sequence.timestamp_ms[np.argmin(tracks.frame)]
    wrong = np.abs(offset - expected) > 0.25 * dt_s * 1000.0
    if wrong.any():
        row = int(np.argmax(wrong))
        raise ImportDataError(
            f"{tracks.source}:{tracks.line[row]}: timestamp_ms {sequence.timestamp_ms[row]:g} "
            f"is not {dt_s:g} s per frame step ({step}) from the sequence's first frame"
        )
    return step


def split_sequences(count: int, config: InteractionConfig) -> list[str]:
    """The split of each of `count` sequences (80/10/10 by default, seeded order)."""
    order = np.random.default_rng(config.seed).permutation(count)
    train = round(config.train_fraction * count)
    val = round(config.val_fraction * count)
    names = ["train"] * train + ["val"] * val + ["test"] * (count - train - val)
    split = [""] * count
    for rank, index in enumerate(order):
        split[int(index)] = names[rank]
    return split


@dataclass(frozen=True)
class Recording:
    """One continuous recording: the case-less files of one folder and number, merged."""

    name: str  # "<folder>/*_tracks_<number>.csv", or the file for another name
    files: tuple[str, ...]  # vehicle file first
    sequence: Sequence  # all their rows, tracks renumbered so the files' ids cannot meet


def group_recordings(sequences: list[Sequence]) -> list[Recording]:
    """The recordings of the case-less files (their single sequences), in input order:
    `vehicle_tracks_N.csv` and `pedestrian_tracks_N.csv` of one folder are one recording, any
    other file is one by itself. ImportDataError if the files of one disagree on the frame grid
    or the clock."""
    groups: dict[tuple[str, str], list[Sequence]] = {}
    for sequence in sequences:
        path = Path(sequence.tracks.source)
        match = RECORDING_FILE.fullmatch(path.name)
        key = (str(path.parent), match[2]) if match else (str(path), "")
        groups.setdefault(key, []).append(sequence)
    recordings = []
    for (where, number), parts in groups.items():
        parts.sort(key=lambda part: Path(part.tracks.source).name.startswith("pedestrian"))
        name = str(Path(where) / f"*_tracks_{number}.csv") if number else where
        recordings.append(Recording(name, tuple(p.tracks.source for p in parts), _merge(parts)))
    return recordings


def _merge(parts: list[Sequence]) -> Sequence:
    if len(parts) == 1:
        return parts[0]
    rank = np.concatenate([np.full(len(p.tracks.agent), i) for i, p in enumerate(parts)])
    agent = np.concatenate([p.tracks.agent for p in parts])
    _, renumbered = np.unique(np.stack([rank, agent], axis=1), axis=0, return_inverse=True)
    first = parts[0].tracks
    return Sequence(
        name=first.source,
        case=-1,
        tracks=Tracks(
            source=" + ".join(p.tracks.source for p in parts),
            line=np.concatenate([p.tracks.line for p in parts]),
            frame=np.concatenate([p.tracks.frame for p in parts]),
            agent=renumbered.reshape(-1).astype(np.int64),
            values=np.concatenate([p.tracks.values for p in parts]),
        ),
        agent_type=np.concatenate([p.agent_type for p in parts]),
        timestamp_ms=np.concatenate([p.timestamp_ms for p in parts]),
    )


def time_blocks(span: int, config: InteractionConfig) -> dict[str, tuple[int, int]]:
    """{split: (first, end)} grid steps of a recording of `span` frame steps: contiguous blocks
    in time, train the first round(0.8 span) steps, val the next round(0.9 span) - round(0.8
    span), test the rest (by default)."""
    train = round(config.train_fraction * span)
    val = round((config.train_fraction + config.val_fraction) * span)
    return {"train": (0, train), "val": (train, val), "test": (val, span)}


def import_interaction(
    inputs: list[str | os.PathLike],
    out: str | os.PathLike,
    config: InteractionConfig,
    overwrite: bool,
    progress: bool = False,
) -> Path:
    """Import the track CSVs `inputs` (files, or folders searched for *.csv) into the file
    `out`, written only once everything has been read (with `progress`, a bar over the files
    read, a line on the windows dropped at split boundaries and one when writing, on stderr).
    Returns the path."""
    out = Path(out)
    check_outputs([out], overwrite)  # before the work, so a refusal is immediate
    paths = _csv_files(inputs)
    found = []
    with reading_bar(len(paths), "read interaction", progress) as bar:
        for path in paths:
            found += read_sequences(path)
            bar.update()
    if not found:
        raise ImportDataError("no track rows in " + ", ".join(str(p) for p in paths))
    sequences = [s for s in found if s.case >= 0]
    for sequence in found:  # each file on its own first: errors name the file and line
        if sequence.case < 0:
            _check_timing(sequence, config.dt_s)
    recordings = group_recordings([s for s in found if s.case < 0])
    every = sequences + [r.sequence for r in recordings]
    with_heading = all(not np.isnan(s.tracks.values[:, 4]).any() for s in every)
    channels = 5 if with_heading else 4
    types = sorted({t for s in every for t in s.agent_type.tolist()})
    parts: dict[str, list] = {split: [] for split in SPLITS}

    def windows_of(sequence: Sequence) -> tuple[int, Windows, np.ndarray]:
        step = _check_timing(sequence, config.dt_s)
        tracks = dataclasses.replace(sequence.tracks, values=sequence.tracks.values[:, :channels])
        windows = cut_windows(tracks, config.num_steps, config.stride)
        type_of = dict(zip(tracks.agent.tolist(), sequence.agent_type.tolist(), strict=True))
        roles = np.array(
            [[types.index(type_of[a]) if a >= 0 else 0 for a in row] for row in windows.agent],
            dtype=np.int8,
        ).reshape(windows.agent.shape)
        return step, windows, roles

    listing = []
    for sequence, split in zip(sequences, split_sequences(len(sequences), config), strict=True):
        step, windows, roles = windows_of(sequence)
        parts[split].append((windows, roles))
        listing.append(
            {
                "sequence": sequence.name,
                "split": split,
                "frame_step": step,
                "windows": windows.count,
            }
        )
    recorded, dropped = [], 0
    for recording in recordings:
        try:
            step, windows, roles = windows_of(recording.sequence)
        except ImportDataError as err:
            raise ImportDataError(
                f"{recording.name}: its files do not share one frame grid and clock ({err})"
            ) from None
        frames = recording.sequence.tracks.frame
        span = 0 if step == 0 else int((frames.max() - frames.min()) // step) + 1
        entry: dict = {"recording": recording.name, "files": list(recording.files)}
        entry |= {"frame_step": step, "frames": {}, "windows": {}}
        inside = np.zeros(windows.count, dtype=bool)
        for split, (first, end) in time_blocks(span, config).items():
            keep = (windows.start >= first) & (windows.start + config.num_steps <= end)
            inside |= keep
            chosen = windows.select(keep)
            parts[split].append((chosen, roles[keep][:, : chosen.agent.shape[1]]))
            ids = [int(frames.min() + step * g) for g in (first, end - 1)] if end > first else None
            entry["frames"][split] = ids
            entry["windows"][split] = int(keep.sum())
        entry["dropped_across_splits"] = int((~inside).sum())
        dropped += entry["dropped_across_splits"]
        recorded.append(entry)
    if recordings and progress:
        print(
            f"{dropped} window(s) across a split boundary of {len(recordings)} recording(s) "
            "dropped",
            file=sys.stderr,
            flush=True,
        )
    splits: dict[str, TrajectorySet] = {
        split: windows_set(part, config.num_steps, channels) for split, part in parts.items()
    }

    def why(split: str) -> str:
        given = sum(entry["split"] == split for entry in listing)
        if recordings:
            low = {"train": 0.0, "val": config.train_fraction}
            low["test"] = config.train_fraction + config.val_fraction
            high = {"train": low["val"], "val": low["test"], "test": 1.0}
            share = round(high[split] - low[split], 9)  # 0.9 - 0.8 is not quite 0.1
            need = (
                f"from about {math.ceil(config.num_steps / share)} frames on" if share else "never"
            )
            held = f" and {given} sequence(s)" if sequences else ""
            return (
                f"its time block ({100 * low[split]:g}-{100 * high[split]:g} % of each "
                f"recording) of {len(recordings)} recording(s){held} holds no whole "
                f"{config.num_steps}-frame window with an agent present throughout; import "
                f"longer recordings (the block holds one {need})"
            )
        if given == 0:
            return (
                f"the split by sequence ({config.train_fraction:g} / {config.val_fraction:g} / "
                f"rest) gives it none of {len(listing)} sequence(s); import more sequences"
            )
        return (
            f"its {given} sequence(s) hold no {config.num_steps}-frame window with an agent "
            "present throughout; import longer ones"
        )

    require_splits(out.name, splits, why)
    description = {"importer": "interaction", "settings": dataclasses.asdict(config)}
    description["sequences"] = listing
    if recordings:
        description["recordings"] = recorded
    meta = DatasetMeta(
        scenario="interaction",
        dt=config.dt_s,
        num_observed=config.num_observed,
        num_predicted=config.num_predicted,
        case_names=("all",),
        major_case="",
        role_names=tuple(types),
        config=description,
        state_names=("x", "y", "vx", "vy", "heading")[:channels],
        action_names=(),
        recorded=("roles",),
    )
    write_all({out: (meta, splits)}, overwrite, progress)
    return out


def _csv_files(inputs: list[str | os.PathLike]) -> list[Path]:
    files = []
    for entry in map(Path, inputs):
        if entry.is_dir():
            files.extend(sorted(entry.rglob("*.csv")))
        elif entry.is_file():
            files.append(entry)
        else:
            raise ImportDataError(f"{entry}: no such file or folder")
    if not files:
        raise ImportDataError("no .csv files in " + ", ".join(str(p) for p in inputs))
    seen: dict[Path, Path] = {}
    for path in files:  # one file read twice would put its sequences into two splits
        first = seen.setdefault(path.resolve(), path)
        if first is not path:
            raise ImportDataError(f"{path}: given twice (also as {first}); name each file once")
    return files
