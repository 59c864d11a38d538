"""What the importers share: the error type, track tables, windowing and all-or-nothing writes."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from predictor.format import DatasetMeta, TrajectorySet, write_dataset


class ImportDataError(ValueError):
    """The input cannot be imported (malformed line, missing folder); the message is one line."""


@dataclass(frozen=True)
class Tracks:
    """Positions of one recording, one row per (frame, agent) observation, sorted by frame."""

    source: str  # file the rows came from (for messages and the file's config)
    line: np.ndarray  # (R,) int64 line number of each row in the source (1-based)
    frame: np.ndarray  # (R,) int64 frame ids
    agent: np.ndarray  # (R,) int64 agent ids
    xy: np.ndarray  # (R, 2) float64 positions [m]


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


def cut_windows(
    tracks: Tracks, num_steps: int, stride: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows of `num_steps` frames on the recording's frame grid (frame_step apart), one
    starting every `stride` grid steps from the first frame, up to the last frame.

    Returns (positions (W, T, A, 2) float32, valid (W, T, A), focal (W, A)), A the largest number
    of agents seen in one window; agents are ordered by id and padded as invalid. Every agent
    seen at any frame of a window is in it; the focal agents are those present at all T frames.
    Windows without a focal agent are dropped (nothing in them would be scored).
    """
    step = frame_step(tracks)
    if step == 0:
        return _no_windows(num_steps)
    grid = (tracks.frame - tracks.frame.min()) // step  # (R,) grid index of each row
    span = int(grid.max()) + 1
    starts = np.arange(0, span - num_steps + 1, stride)
    if len(starts) == 0:
        return _no_windows(num_steps)
    agents, column = np.unique(tracks.agent, return_inverse=True)  # (P,), (R,)
    table = np.zeros((span, len(agents), 2))
    present = np.zeros((span, len(agents)), dtype=bool)
    table[grid, column] = tracks.xy
    present[grid, column] = True
    windows = []
    for start in starts:
        here = present[start : start + num_steps]  # (T, P)
        seen = np.flatnonzero(here.any(axis=0))
        full = here[:, seen].all(axis=0)
        if full.any():
            windows.append((start, seen, full))
    if not windows:
        return _no_windows(num_steps)
    width = max(len(seen) for _, seen, _ in windows)
    positions = np.zeros((len(windows), num_steps, width, 2), dtype=np.float32)
    valid = np.zeros((len(windows), num_steps, width), dtype=bool)
    focal = np.zeros((len(windows), width), dtype=bool)
    for w, (start, seen, full) in enumerate(windows):
        rows = slice(start, start + num_steps)
        valid[w, :, : len(seen)] = present[rows][:, seen]
        positions[w, :, : len(seen)] = np.where(
            valid[w, :, : len(seen), None], table[rows][:, seen], 0.0
        )
        focal[w, : len(seen)] = full
    return positions, valid, focal


def _no_windows(num_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.zeros((0, num_steps, 0, 2), np.float32),
        np.zeros((0, num_steps, 0), bool),
        np.zeros((0, 0), bool),
    )


def positions_only_set(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], num_steps: int
) -> TrajectorySet:
    """One split from the windows of several recordings: positions, validity and focal mask
    only (the optional datasets hold their neutral values), agent axis padded to the widest."""
    sets = []
    for positions, valid, focal in parts:
        n, _, agents = valid.shape
        sets.append(
            TrajectorySet(
                states=positions,
                actions=np.zeros((n, num_steps, agents, 0), np.float32),
                valid=valid,
                attention=np.full((n, num_steps, agents), -1, np.int16),
                interaction=np.zeros((n, num_steps), bool),
                case=np.zeros(n, np.int8),
                seed=np.full(n, -1, np.int64),
                roles=np.zeros((n, agents), np.int8),
                focal=focal,
            )
        )
    if not sets:
        return TrajectorySet.empty(num_steps, 0, num_states=2, num_actions=0)
    return TrajectorySet.concatenate(sets)


def check_outputs(paths: list[Path], overwrite: bool) -> None:
    """ImportDataError unless every output can be written: directory exists, no file is in the
    way (unless `overwrite`), none is a directory."""
    for path in paths:
        if path.is_dir():
            raise ImportDataError(f"output {path} is a directory")
        if path.exists() and not overwrite:
            raise ImportDataError(f"output {path} already exists; pass --overwrite to replace it")
        if not path.parent.is_dir():
            raise ImportDataError(f"output directory {path.parent} does not exist")


def write_all(
    files: Mapping[Path, tuple[DatasetMeta, Mapping[str, TrajectorySet]]], overwrite: bool
) -> list[Path]:
    """Write every file, all or nothing: each goes to a temporary name first and they are
    renamed onto their targets only once all are written."""
    check_outputs(list(files), overwrite)
    temps: dict[Path, Path] = {}
    try:
        for path, (meta, splits) in files.items():
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
