"""ETH/UCY pedestrians in the widely used raw text layout, as schema-2 files (one per scene).

Input: a root folder with one folder per scene (`eth`, `hotel`, `univ`, `zara1`, `zara2`), each
holding `train/`, `val/` and `test/` folders of text files; each line is `frame ped x y` (frame
id, pedestrian id, position [m]), whitespace or tab separated. This is the standard leave-one-out
protocol: a scene's `test/` holds that scene, its `train/` and `val/` the other four.

Windows (`EthUcyConfig`): 8 observed + 12 predicted steps of 0.4 s, i.e. 20 frames, one window
starting at every step (stride 1). A file's frame-id step is derived from the data (the most
common gap between its frame ids: 10 in most files, 6 in biwi_eth), so a window covers frame ids
f, f + step, ..., f + 19 step. Every pedestrian seen in a window is one of its agents (valid where
observed); the pedestrians present at all 20 frames are its focal agents, the ones scored by the
metrics and choosing checkpoints, as the usual evaluation counts them. A window is kept only when
it has at least `min_focal_agents` focal pedestrians, 2 by default: Social-GAN's loader
(Gupta et al., CVPR 2018, `sgan/data/trajectories.py`: `num_peds_considered > min_ped` with
min_ped = 1), whose windows most ETH/UCY tables and Schöller et al.'s constant-velocity paper use.
The rule of this importer before that default, any focal pedestrian, is `min_focal_agents=1`.

A scene whose train, val or test split would hold no window is refused (ImportDataError naming
the split and what to change), and then no file is written.

Output: `<out>/eth_ucy_<scene>.h5` per scene, states x, y only, nothing optional recorded, one
role ("pedestrian"), one case ("all"); the file's config lists every source file with its frame
step and its pedestrian, window and focal-agent counts.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from trajectory_data.format import SPLITS, DatasetMeta, TrajectorySet
from trajectory_data.importers.common import (
    MAX_ID,
    ImportDataError,
    Tracks,
    check_outputs,
    cut_windows,
    frame_step,
    reading_bar,
    require_splits,
    windows_set,
    write_all,
)

SCENES = ("eth", "hotel", "univ", "zara1", "zara2")


@dataclass(frozen=True)
class EthUcyConfig:
    """Protocol of the import (defaults: the standard 8 + 12 steps at 0.4 s, stride 1, windows
    with at least two focal pedestrians as Social-GAN's)."""

    num_observed: int = 8  # observed steps (3.2 s)
    num_predicted: int = 12  # predicted steps (4.8 s)
    dt_s: float = 0.4  # [s] between two annotated frames (2.5 Hz)
    stride: int = 1  # steps between the starts of consecutive windows
    scenes: tuple[str, ...] = SCENES  # scenes to import; each needs its folder under the root
    # a window is kept when at least this many pedestrians are present at all its frames; 2 is
    # Social-GAN's rule (its windows are the field's tables'), 1 keeps single-pedestrian windows
    min_focal_agents: int = 2

    def __post_init__(self) -> None:
        checks = {
            "num_observed": self.num_observed >= 2,
            "num_predicted": self.num_predicted >= 1,
            "dt_s": math.isfinite(self.dt_s) and self.dt_s > 0,
            "stride": self.stride >= 1,
            "scenes": len(self.scenes) > 0 and len(set(self.scenes)) == len(self.scenes),
            "min_focal_agents": self.min_focal_agents >= 1,
        }
        for name, ok in checks.items():
            if not ok:
                raise ValueError(f"EthUcyConfig.{name} is out of range: {getattr(self, name)!r}")

    @property
    def num_steps(self) -> int:
        """Frames per window, T."""
        return self.num_observed + self.num_predicted


def read_tracks(path: Path) -> Tracks:
    """Parse one `frame ped x y` file; ImportDataError naming the file and line for a line that
    is not four finite numbers with integral frame and pedestrian ids, or a repeated pair."""
    lines, rows = [], []
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark is not data
    except (OSError, UnicodeDecodeError) as err:
        raise ImportDataError(f"{path}: cannot read ({err})") from None
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        rows.append(_parse_line(path, number, fields))
        lines.append(number)
    table = np.array(rows, dtype=np.float64).reshape(-1, 4)
    tracks = Tracks(
        source=str(path),
        line=np.array(lines, dtype=np.int64),
        frame=table[:, 0].astype(np.int64),
        agent=table[:, 1].astype(np.int64),
        values=table[:, 2:],
    )
    _check_unique(tracks)
    return tracks


def _parse_line(path: Path, number: int, fields: list[str]) -> list[float]:
    where = f"{path}:{number}"
    if len(fields) != 4:
        raise ImportDataError(f"{where}: expected 4 fields 'frame ped x y', got {len(fields)}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise ImportDataError(f"{where}: not a number in {' '.join(fields)!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ImportDataError(f"{where}: non-finite value in {' '.join(fields)!r}")
    for name, value in (("frame", values[0]), ("ped", values[1])):
        if not value.is_integer():
            raise ImportDataError(f"{where}: {name} id {value!r} is not an integer")
        if abs(value) >= MAX_ID:
            raise ImportDataError(f"{where}: {name} id {value:.0f} is beyond 2**53")
    return values


def _check_unique(tracks: Tracks) -> None:
    pairs = np.stack([tracks.frame, tracks.agent], axis=1)
    _, first, counts = np.unique(pairs, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        frame, agent = pairs[first[counts > 1][0]]
        again = np.flatnonzero((tracks.frame == frame) & (tracks.agent == agent))[1]
        raise ImportDataError(
            f"{tracks.source}:{tracks.line[again]}: pedestrian {agent} appears twice in "
            f"frame {frame}"
        )


def scene_files(root: Path, scene: str) -> dict[str, list[Path]]:
    """{split: sorted .txt files} of a scene's folder; ImportDataError if a split folder is
    missing."""
    files = {}
    for split in SPLITS:
        folder = root / scene / split
        if not folder.is_dir():
            raise ImportDataError(f"{folder}: missing folder (expected {scene}/{'|'.join(SPLITS)})")
        files[split] = sorted(p for p in folder.iterdir() if p.suffix == ".txt" and p.is_file())
    return files


def import_scene(
    root: Path, scene: str, config: EthUcyConfig, on_file: Callable[[], None] | None = None
) -> tuple[DatasetMeta, dict[str, TrajectorySet]]:
    """The schema-2 metadata and splits of one leave-one-out scene (`on_file()` after each
    file read: progress)."""
    splits, sources = {}, {}
    for split, paths in scene_files(root, scene).items():
        parts, sources[split] = [], []
        for path in paths:
            tracks = read_tracks(path)
            if on_file is not None:
                on_file()
            windows = cut_windows(tracks, config.num_steps, config.stride, config.min_focal_agents)
            parts.append((windows, None))
            sources[split].append(
                {
                    "file": os.path.relpath(path, root),
                    "frame_step": frame_step(tracks),
                    "pedestrians": len(np.unique(tracks.agent)),
                    "windows": windows.count,
                    "focal_agents": int(windows.focal.sum()),
                }
            )
        splits[split] = windows_set(parts, config.num_steps, num_channels=2)

    def why(split: str) -> str:
        folder = root / scene / split
        if not sources[split]:
            return f"{folder} holds no .txt file; add that split's files"
        rule = f"{config.min_focal_agents} pedestrian(s) present at all {config.num_steps} frames"
        change = (
            f"lower --min-focal-agents (min_focal_agents, now {config.min_focal_agents})"
            if config.min_focal_agents > 1
            else "its tracks are all shorter than a window; add longer ones"
        )
        return f"no window of {folder}/*.txt has {rule}; {change}"

    require_splits(f"eth_ucy_{scene}.h5", splits, why)
    meta = DatasetMeta(
        scenario=f"eth_ucy_{scene}",
        dt=config.dt_s,
        num_observed=config.num_observed,
        num_predicted=config.num_predicted,
        case_names=("all",),
        major_case="",
        role_names=("pedestrian",),
        config={"importer": "eth-ucy", "settings": dataclasses.asdict(config), "sources": sources},
        state_names=("x", "y"),
        action_names=(),
        recorded=(),
    )
    return meta, splits


def import_eth_ucy(
    root: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: EthUcyConfig,
    overwrite: bool,
    progress: bool = False,
) -> list[Path]:
    """Import every scene of `config.scenes` under `root` into `out_dir/eth_ucy_<scene>.h5`;
    all files or none are written (with `progress`, a bar over the files read and a line
    when writing, on stderr). Returns the paths."""
    root, out_dir = Path(root), Path(out_dir)
    if not root.is_dir():
        raise ImportDataError(f"{root}: no such folder")
    outputs = [out_dir / f"eth_ucy_{scene}.h5" for scene in config.scenes]
    check_outputs(outputs, overwrite)  # before the work, so a refusal is immediate
    count = sum(len(p) for scene in config.scenes for p in scene_files(root, scene).values())
    with reading_bar(count, "read eth-ucy", progress) as bar:
        files = {
            path: import_scene(root, scene, config, lambda: bar.update())
            for path, scene in zip(outputs, config.scenes, strict=True)
        }
    return write_all(files, overwrite, progress)
