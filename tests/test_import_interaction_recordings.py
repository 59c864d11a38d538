"""tools/import_data.py interaction on continuous recordings as the INTERACTION release ships
them (`<location>/vehicle_tracks_NNN.csv` and `pedestrian_tracks_NNN.csv`, no case_id): windows
and time blocks counted by hand, frame ranges read back from the written file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import run_tool

from trajectory_data.format import SPLITS
from trajectory_data.importers.common import ImportDataError
from trajectory_data.importers.interaction import InteractionConfig, import_interaction
from trajectory_data.reader import read_dataset

VEHICLES = "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width"
PEDESTRIANS = "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy"


def vehicle_file(path: Path, frames: range, x0: float = 0.0) -> None:
    """Track 1, a car at every frame of `frames`: x = x0 + 0.5 frame (so a window's first and
    last frame can be read back from its states), y = 3."""
    rows = [f"1,{f},{100 * f},car,{x0 + 0.5 * f},3.0,5.0,0.0,0.0,4.0,1.8" for f in frames]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join([VEHICLES, *rows]) + "\n")


def pedestrian_file(path: Path, tracks: dict[str, range], clock_ms: int = 0) -> None:
    """Pedestrians numbered as shipped (P1, P2, ...), track Pk at y = 100 k."""
    rows = [
        f"{name},{f},{100 * f + clock_ms},pedestrian/bicycle,{0.1 * f},{100.0 * int(name[1:])},1,0"
        for name, frames in tracks.items()
        for f in frames
    ]
    path.write_text("\n".join([PEDESTRIANS, *rows]) + "\n")


def write_location(root: Path) -> Path:
    """Recording 000: frames 1..2000 (grid steps 0..1999), car 1 throughout, pedestrian P1
    throughout and P2 at frames 500..700; recording 001: frames 1..1000, car 1 alone (x + 10000).
    Time blocks 80/10/10 of each recording's steps; windows of 100 frames every 10 steps:
    000: train steps 0..1599 (frames 1..1600), windows starting at steps 0..1500: 151; val steps
    1600..1799: starts 1600..1700, 11; test steps 1800..1999: 11; dropped (crossing): starts
    1510..1590 and 1710..1790, 18. 001: train starts 0..700 (71), val 800 (1), test 900 (1),
    dropped 9 + 9 = 18."""
    location = root / "DR_TEST_Location"
    vehicle_file(location / "vehicle_tracks_000.csv", range(1, 2001))
    pedestrian_file(
        location / "pedestrian_tracks_000.csv", {"P1": range(1, 2001), "P2": range(500, 701)}
    )
    vehicle_file(location / "vehicle_tracks_001.csv", range(1, 1001), x0=10000.0)
    return location


def test_recordings_split_by_time_blocks_pedestrians_joining(tmp_path: Path) -> None:
    location = write_location(tmp_path / "raw")
    out = tmp_path / "inter.h5"
    result = run_tool("import_data.py", "interaction", tmp_path / "raw", "--out", out)
    assert result.returncode == 0, result.stderr
    assert "36 window(s) across a split boundary of 2 recording(s) dropped" in result.stderr
    meta, splits = read_dataset(out)
    assert [splits[s].n for s in SPLITS] == [151 + 71, 11 + 1, 11 + 1]
    assert meta.role_names == ("car", "pedestrian/bicycle")
    assert meta.state_names == ("x", "y", "vx", "vy")  # pedestrians have no psi_rad
    assert meta.config["sequences"] == []
    first, second = meta.config["recordings"]
    assert first["recording"] == str(location / "*_tracks_000.csv")
    assert first["files"] == [
        str(location / "vehicle_tracks_000.csv"),
        str(location / "pedestrian_tracks_000.csv"),
    ]
    assert first["frames"] == {"train": [1, 1600], "val": [1601, 1800], "test": [1801, 2000]}
    assert first["windows"] == {"train": 151, "val": 11, "test": 11}
    assert first["dropped_across_splits"] == 18
    assert second["files"] == [str(location / "vehicle_tracks_001.csv")]
    assert second["frames"] == {"train": [1, 800], "val": [801, 900], "test": [901, 1000]}
    assert second["windows"] == {"train": 71, "val": 1, "test": 1}
    assert second["dropped_across_splits"] == 18
    ranges = {0: first["frames"], 10000: second["frames"]}
    for split, data in splits.items():
        x = data.states[:, :, 0, 0].astype(np.float64)  # the car, slot 0, present throughout
        assert data.valid[:, :, 0].all()
        offset = np.where(x[:, 0] >= 10000, 10000, 0)
        begin = np.round((x[:, 0] - offset) / 0.5).astype(int)
        end = np.round((x[:, -1] - offset) / 0.5).astype(int)
        assert (end - begin == 99).all()
        for o, b, e in zip(offset.tolist(), begin.tolist(), end.tolist(), strict=True):
            low, high = ranges[o][split]
            assert low <= b and e <= high  # no window crosses its split's frame range
        own = offset == 0  # recording 000: P1 (slot 1) joins every window, a pedestrian
        assert data.valid[own, :, 1].all() and np.allclose(data.states[own, :, 1, 1], 100.0)
        assert (data.roles[own, :2] == [0, 1]).all() and data.focal[own, :2].all()
        assert not data.valid[~own, :, 1:].any()  # 001 has no pedestrian file
    # P2 (frames 500..700, 201 frames) is in the train windows starting at frames 401..691,
    # focal (all 100 frames) in those starting at 501..601
    train = splits["train"]
    x0 = train.states[:, 0, 0, 0].astype(np.float64)
    begin = np.where(x0 < 10000, np.round(x0 / 0.5), -1).astype(int)
    assert train.valid[:, :, 2].any(axis=1).tolist() == ((begin >= 401) & (begin <= 691)).tolist()
    assert train.focal[:, 2].tolist() == ((begin >= 501) & (begin <= 601)).tolist()
    assert int(train.focal[:, 2].sum()) == 11
    assert (train.roles[train.valid[:, :, 2].any(axis=1), 2] == 1).all()


def test_short_recording_leaves_a_split_empty_and_is_refused(tmp_path: Path) -> None:
    vehicle_file(tmp_path / "raw" / "vehicle_tracks_000.csv", range(1, 501))  # val: 50 frames
    out = tmp_path / "inter.h5"
    result = run_tool("import_data.py", "interaction", tmp_path / "raw", "--out", out)
    assert result.returncode == 2 and not out.exists()
    assert result.stderr.strip().splitlines()[-1] == (
        "error: inter.h5: the val split would be empty: its time block (80-90 % of each "
        "recording) of 1 recording(s) holds no whole 100-frame window with an agent present "
        "throughout; import longer recordings (the block holds one from about 1000 frames on)"
    )


def test_files_of_one_recording_must_share_the_clock(tmp_path: Path) -> None:
    location = tmp_path / "raw"
    vehicle_file(location / "vehicle_tracks_000.csv", range(1, 1001))
    pedestrian_file(location / "pedestrian_tracks_000.csv", {"P1": range(1, 1001)}, clock_ms=50)
    with pytest.raises(ImportDataError, match=r"_tracks_000.csv: its files do not share one"):
        import_interaction([location], tmp_path / "o.h5", InteractionConfig(), overwrite=False)


def test_pedestrian_ids_as_shipped_in_errors(tmp_path: Path) -> None:
    path = tmp_path / "pedestrian_tracks_000.csv"
    pedestrian_file(path, {"P7": [1, 2, 2]})
    with pytest.raises(ImportDataError, match=rf"^{path}:4: track P7 appears twice in frame 2$"):
        import_interaction([path], tmp_path / "o.h5", InteractionConfig(), overwrite=False)
