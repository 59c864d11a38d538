"""What the importers share: the error type, track tables, windowing and all-or-nothing writes."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from trajectory_data.format import DatasetMeta, TrajectorySet, write_dataset

# ids (frames, agents, cases) are read as float64, exact up to 2**53; larger ones are refused
MAX_ID = 2**53


class ImportDataError(ValueError):
    """The input cannot be imported (malformed line, missing folder); the message is one line."""


@dataclass(frozen=True)
class Tracks:
    """One recording (a sequence), one row per (frame, agent) observation."""

    source: str  # file the rows came from (for messages and the file's config)
    line: np.ndarray  # (R,) int64 line number of each row in the source (1-based)
    frame: np.ndarray  # (R,) int64 frame ids
    agent: np.ndarray  # (R,) int64 agent ids
    values: np.ndarray  # (R, C) float64 state channels, x [m] and y [m] first


@dataclass(frozen=True)
class Windows:
    """The windows cut from one recording (W windows, T steps, A agent slots, C channels)."""

    states: np.ndarray  # (W, T, A, C) float32, 0 where invalid
    valid: np.ndarray  # (W, T, A) bool
    focal: np.ndarray  # (W, A) bool: present at all T steps
    agent: np.ndarray  # (W, A) int64 agent id of each slot, -1 for padding
    start: np.ndarray  # (W,) int64 grid step of each window's first frame (0: the first frame)

    @property
    def count(self) -> int:
        """Number of windows, W."""
        return int(self.valid.shape[0])

    def select(self, keep: np.ndarray) -> Windows:
        """The windows where `keep` (W,) bool is true, the agent axis cut to the widest of them."""
        width = int((self.agent[keep] >= 0).sum(axis=1).max(initial=0))
        return Windows(
            states=self.states[keep][:, :, :width],
            valid=self.valid[keep][:, :, :width],
            focal=self.focal[keep][:, :width],
            agent=self.agent[keep][:, :width],
            start=self.start[keep],
        )


def frame_step(tracks: Tracks) -> int:
    """The recording's frame-id step: the most common gap between consecutive distinct frame
    ids (0 for fewer than two frames). ETH/UCY files step by 10 (biwi_eth by 6); a larger gap is
    a stretch without observations. ImportDataError, naming the line, for a frame off that grid
    (ids that do not step evenly cannot be given a time)."""
    distinct = np.unique(tracks.frame)
    if len(distinct) < 2:
        return 0
    gaps, counts = np.unique(np.diff(distinct), return_counts=True)
    step = int(gaps[np.argmax(counts)])
    off = (tracks.frame - distinct[0]) % step != 0
    if off.any():
        row = int(np.argmax(off))
        raise ImportDataError(
            f"{tracks.source}:{tracks.line[row]}: frame {tracks.frame[row]} is off the file's "
            f"frame grid (first frame {distinct[0]}, step {step})"
        )
    return step


def cut_windows(tracks: Tracks, num_steps: int, stride: int, min_focal: int = 1) -> Windows:
    """Windows of `num_steps` frames on the recording's frame grid (frame_step apart), one
    starting every `stride` grid steps from the first frame, up to the last frame.

    Agents are ordered by id and padded as invalid up to A, the largest number of agents seen
    in one window. Every agent seen at any frame of a window is in it; the focal agents are
    those present at all T frames. Windows with fewer than `min_focal` focal agents are dropped
    (with the default 1: those where nothing would be scored).
    """
    channels = tracks.values.shape[1]
    step = frame_step(tracks)
    span = 0 if step == 0 else int((tracks.frame.max() - tracks.frame.min()) // step) + 1
    starts = np.arange(0, span - num_steps + 1, stride)
    agents, column = np.unique(tracks.agent, return_inverse=True)  # (P,), (R,)
    table = np.zeros((span, len(agents), channels))
    present = np.zeros((span, len(agents)), dtype=bool)
    if len(starts):
        grid = (tracks.frame - tracks.frame.min()) // step  # (R,) grid index of each row
        table[grid, column] = tracks.values
        present[grid, column] = True
    chosen = []
    for start in starts:
        here = present[start : start + num_steps]  # (T, P)
        seen = np.flatnonzero(here.any(axis=0))
        if here[:, seen].all(axis=0).sum() >= max(min_focal, 1):
            chosen.append((start, seen))
    width = max((len(seen) for _, seen in chosen), default=0)
    out = Windows(
        states=np.zeros((len(chosen), num_steps, width, channels), dtype=np.float32),
        valid=np.zeros((len(chosen), num_steps, width), dtype=bool),
        focal=np.zeros((len(chosen), width), dtype=bool),
        agent=np.full((len(chosen), width), -1, dtype=np.int64),
        start=np.array([start for start, _ in chosen], dtype=np.int64),
    )
    for w, (start, seen) in enumerate(chosen):
        rows, slots = slice(start, start + num_steps), slice(0, len(seen))
        out.valid[w, :, slots] = present[rows][:, seen]
        out.states[w, :, slots] = np.where(out.valid[w, :, slots, None], table[rows][:, seen], 0)
        out.focal[w, slots] = out.valid[w, :, slots].all(axis=0)
        out.agent[w, slots] = agents[seen]
    return out


def windows_set(
    parts: list[tuple[Windows, np.ndarray | None]],
    num_steps: int,
    num_channels: int,
) -> TrajectorySet:
    """One split from the windows of several recordings, each with its slots' roles (W, A) int8
    or None (role 0): states, validity, focal mask and roles (the other optional datasets hold
    their neutral values), agent axis padded to the widest."""
    sets = []
    for windows, roles in parts:
        n, _, agents = windows.valid.shape
        sets.append(
            TrajectorySet(
                states=windows.states,
                actions=np.zeros((n, num_steps, agents, 0), np.float32),
                valid=windows.valid,
                attention=np.full((n, num_steps, agents), -1, np.int16),
                interaction=np.zeros((n, num_steps), bool),
                case=np.zeros(n, np.int8),
                seed=np.full(n, -1, np.int64),
                roles=np.zeros((n, agents), np.int8) if roles is None else roles,
                focal=windows.focal,
            )
        )
    if not sets:
        return TrajectorySet.empty(num_steps, 0, num_states=num_channels, num_actions=0)
    return TrajectorySet.concatenate(sets)


def require_splits(
    name: str, splits: Mapping[str, TrajectorySet], why: Callable[[str], str]
) -> None:
    """ImportDataError, one line naming the file `name`, the first empty split and `why(split)`
    (what left it empty and what to change), unless every split holds a window: a file without
    training windows trains nothing, one without validation or test windows chooses or scores
    nothing, and each would fail only later, far from its cause."""
    for split, data in splits.items():
        if data.n == 0:
            raise ImportDataError(f"{name}: the {split} split would be empty: {why(split)}")


def check_outputs(paths: list[Path], overwrite: bool) -> None:
    """ImportDataError unless every output can be written: its directory exists or can be
    created (no file in the way), no file is in the way (unless `overwrite`), none is a
    directory."""
    for path in paths:
        if path.is_dir():
            raise ImportDataError(f"output {path} is a directory")
        if path.exists() and not overwrite:
            raise ImportDataError(f"output {path} already exists; pass --overwrite to replace it")
        existing = next(p for p in path.parents if p.exists())  # missing ones are created
        if not existing.is_dir():
            raise ImportDataError(f"output directory {path.parent}: {existing} is not a directory")


READING_BAR_DELAY_S = 2.0  # a read that ends sooner (or fails on a malformed line) shows none


def reading_bar(files: int, desc: str, enabled: bool) -> tqdm:
    """A progress bar on stderr over the input files an importer reads (silent if not
    `enabled`), shown once reading has taken READING_BAR_DELAY_S: a quick import, and the one
    error line of a malformed input found early, come without it."""
    return tqdm(
        total=files,
        desc=desc,
        unit="file",
        disable=not enabled,
        file=sys.stderr,
        delay=READING_BAR_DELAY_S,
    )


def write_all(
    files: Mapping[Path, tuple[DatasetMeta, Mapping[str, TrajectorySet]]],
    overwrite: bool,
    progress: bool = False,
) -> list[Path]:
    """Write every file, all or nothing: each goes to a temporary name first and they are
    renamed onto their targets only once all are written (missing directories are created).
    With `progress`, a line on stderr says so first."""
    check_outputs(list(files), overwrite)
    if progress:
        print(f"writing {len(files)} file(s)", file=sys.stderr, flush=True)
    temps: dict[Path, Path] = {}
    try:
        for path, (meta, splits) in files.items():
            path.parent.mkdir(parents=True, exist_ok=True)
            temp = path.with_name(f".{path.name}.{os.getpid()}.import.tmp")
            temps[path] = write_dataset(temp, meta, splits, overwrite=True)
        for path, temp in temps.items():
            os.replace(temp, path)
    except BaseException:
        for temp in temps.values():
            with contextlib.suppress(OSError):
                temp.unlink(missing_ok=True)
        raise
    return list(files)
