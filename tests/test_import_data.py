"""tools/import_data.py eth-ucy on small hand-made files in the raw ETH/UCY layout: windows
counted by hand, read back through trajectory_data.format, bad input refused in one line."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import run_tool

from predictor.evaluation import evaluate_baseline, evaluate_run
from predictor.presets import make_configs
from predictor.training import train
from trajectory_data.format import SPLITS
from trajectory_data.importers.common import ImportDataError, Tracks, frame_step
from trajectory_data.importers.eth_ucy import EthUcyConfig, import_eth_ucy
from trajectory_data.importers.interaction import InteractionConfig, import_interaction
from trajectory_data.reader import read_dataset, read_split
from trajectory_data.torch_dataset import TrajectoryDataset


def position(ped: int, grid: int) -> tuple[float, float]:
    """Where pedestrian `ped` is at grid step `grid` [m]: curved, so velocity changes."""
    return ped + 0.1 * grid, -ped + 0.05 * grid * grid


def rows(ped: int, grids, first_frame: int = 100, step: int = 10) -> list[tuple]:
    return [(first_frame + step * g, ped, *position(ped, g)) for g in grids]


def write_file(path: Path, table: list[tuple], sep: str = "\t") -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [sep.join(f"{v:.1f}" if i < 2 else f"{v:.6f}" for i, v in enumerate(r)) for r in table]
    path.write_text("\n".join(lines) + "\n")


def make_scene(root: Path) -> None:
    """Scene `hotel`. train/a.txt (frames 100 + 10 g, grid steps g):
    ped 1 at g = 0..22; ped 2 at g = 2..21; ped 3 at g = 5..9; ped 4 at g = 23 only;
    ped 5 at g = 40..59 (nobody at g = 24..39: frame ids jump by 170 there).
    Windows of 20 steps start at g = 0..40; with a focal (fully present) pedestrian: g = 0..3
    (ped 1; ped 2 as well at g = 2) and g = 40 (ped 5), i.e. 5 windows, 3 agent slots at most.
    train/b.txt steps by 6 (as biwi_eth): ped 7 at 20 frames, 1 window.
    val/c.txt: ped 1 at 20 frames, ped 2 at the first 3: 1 window with 2 agents, 1 focal.
    test/d.txt: ped 1 at 21 frames: 2 windows."""
    scene = root / "hotel"
    table = rows(1, range(23)) + rows(2, range(2, 22)) + rows(3, range(5, 10)) + rows(4, [23])
    table += rows(5, range(40, 60))
    table.sort(key=lambda r: (r[0], r[1]))  # frame-major, as distributed
    write_file(scene / "train" / "a.txt", table)
    write_file(scene / "train" / "b.txt", rows(7, range(20), first_frame=0, step=6), sep=" ")
    write_file(scene / "val" / "c.txt", rows(1, range(20)) + rows(2, range(3)))
    write_file(scene / "test" / "d.txt", rows(1, range(21)))


def run_importer(*args: object) -> subprocess.CompletedProcess:
    return run_tool("import_data.py", *args)


# make_scene's counts are under the rule before Social-GAN's: any focal pedestrian keeps a window
ANY = ("--min-focal-agents", "1")


def make_pairs_scene(root: Path, scene: str = "zara1") -> None:
    """Scene `zara1` (or `scene`) for the two-focal-pedestrian rule (frames 100 + 10 g, grid
    steps g).
    train/a.txt: ped 1 at g = 0..24, ped 2 at g = 3..24, ped 3 at g = 0..19. Windows start at
    g = 0..5; focal there: {1, 3}, {1}, {1}, {1, 2}, {1, 2}, {1, 2}. Two or more: starts 0, 3, 4,
    5 (4 windows); at least one: all 6 (starts 1 and 2 hold peds 2 and 3 in part, not focal).
    val/b.txt: peds 1, 2 at g = 0..19: 1 window with 2 focal (either rule).
    test/c.txt: peds 1, 2, 3 at g = 0..20 (windows at 0 and 1, 3 focal each), ped 4 alone at
    g = 30..49 (1 window, 1 focal): 2 windows, or 3 with the old rule."""
    folder = root / scene
    write_file(
        folder / "train" / "a.txt", rows(1, range(25)) + rows(2, range(3, 25)) + rows(3, range(20))
    )
    write_file(folder / "val" / "b.txt", rows(1, range(20)) + rows(2, range(20)))
    table = [r for ped in (1, 2, 3) for r in rows(ped, range(21))] + rows(4, range(30, 50))
    write_file(folder / "test" / "c.txt", table)


@pytest.mark.parametrize(
    ("flags", "rule", "counts", "starts"),
    [
        ((), 2, [4, 1, 2], [0, 3, 4, 5]),
        (("--min-focal-agents", "2"), 2, [4, 1, 2], [0, 3, 4, 5]),
        (ANY, 1, [6, 1, 3], [0, 1, 2, 3, 4, 5]),
    ],
)
def test_windows_need_two_focal_pedestrians_by_default(tmp_path, flags, rule, counts, starts):
    make_pairs_scene(tmp_path / "raw")
    out = tmp_path / "out"
    result = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "zara1", *flags)
    assert result.returncode == 0, result.stderr
    meta, splits = read_dataset(out / "eth_ucy_zara1.h5")
    assert [splits[s].n for s in SPLITS] == counts
    assert meta.config["settings"]["min_focal_agents"] == rule
    train = splits["train"]
    # slot 0 is ped 1, present throughout: its first x (1 + 0.1 g) gives the window's start g
    first_x = train.states[:, 0, 0, 0]
    assert np.round((first_x - 1) / 0.1).astype(int).tolist() == starts
    focal_sets = {0: [1, 3], 1: [1], 2: [1], 3: [1, 2], 4: [1, 2], 5: [1, 2]}
    for w, start in enumerate(starts):  # slots: peds 1, 2, 3 in id order
        assert np.flatnonzero(train.focal[w]).tolist() == [p - 1 for p in focal_sets[start]]
    assert (splits["val"].focal.sum(axis=1) == 2).all()
    assert splits["test"].focal.sum(axis=1).tolist() == [3, 3, 1][: counts[2]]
    windows = {s["file"]: s["windows"] for s in meta.config["sources"]["test"]}
    assert windows == {"zara1/test/c.txt": counts[2]}


def test_min_focal_agents_below_one_is_refused(tmp_path: Path) -> None:
    make_pairs_scene(tmp_path / "raw")
    out = tmp_path / "out"
    result = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--min-focal-agents", "0")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "error: EthUcyConfig.min_focal_agents is out of range: 0"
    ]
    assert not out.exists()


def test_windows_counted_by_hand_read_back(tmp_path: Path) -> None:
    make_scene(tmp_path / "raw")
    out = tmp_path / "out"
    out.mkdir()
    result = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel", *ANY)
    assert result.returncode == 0, result.stderr
    assert result.stderr == "writing 1 file(s)\n"  # no silent phase; a quick read shows no bar
    path = out / "eth_ucy_hotel.h5"
    assert sorted(p.name for p in out.iterdir()) == ["eth_ucy_hotel.h5"]  # no temporary left
    meta, splits = read_dataset(path)
    assert (meta.dt, meta.num_observed, meta.num_predicted) == (0.4, 8, 12)
    assert meta.state_names == ("x", "y") and meta.recorded == ()
    assert meta.scenario == "eth_ucy_hotel"
    assert [splits[s].n for s in ("train", "val", "test")] == [6, 1, 2]
    train = splits["train"]
    assert train.num_agents == 3
    # windows of a.txt start at g = 0, 1, 2, 3, 40, then b.txt's one window; slots by ped id
    assert train.focal.tolist() == [
        [True, False, False],
        [True, False, False],
        [True, True, False],
        [True, False, False],
        [True, False, False],  # g = 40: ped 5 alone
        [True, False, False],  # b.txt: ped 7
    ]
    assert train.valid[4].sum(axis=0).tolist() == [20, 0, 0]
    window = train.states[2]  # g = 2..21: peds 1, 2, 3
    for k in range(20):
        assert tuple(window[k, 0]) == pytest.approx(position(1, 2 + k))
        assert tuple(window[k, 1]) == pytest.approx(position(2, 2 + k))
    assert train.valid[2, :, 2].tolist() == [5 <= g <= 9 for g in range(2, 22)]  # ped 3: 5..9
    assert (train.states[2, :, 2][~train.valid[2, :, 2]] == 0).all()
    assert tuple(train.states[5, 19, 0]) == pytest.approx(position(7, 19))
    sources = {s["file"]: s for s in meta.config["sources"]["train"]}
    assert sources["hotel/train/a.txt"]["frame_step"] == 10
    assert sources["hotel/train/b.txt"]["frame_step"] == 6
    assert sources["hotel/train/a.txt"]["windows"] == 5
    assert splits["val"].focal.tolist() == [[True, False]]
    assert f"wrote 1 file(s): {path}" in result.stdout


def test_constant_velocity_equals_an_independent_computation(tmp_path: Path) -> None:
    make_scene(tmp_path / "raw")
    config = EthUcyConfig(scenes=("hotel",), min_focal_agents=1)
    paths = import_eth_ucy(tmp_path / "raw", tmp_path, config, False)
    scores = evaluate_baseline("const_vel", paths[0], "test").scores["main_agents"]["overall"]
    errors = []  # test/d.txt: ped 1 at g = 0..20, windows start at g = 0 and 1
    for start in (0, 1):
        last = np.array(position(1, start + 7))
        velocity = last - np.array(position(1, start + 6))
        for k in range(1, 13):
            errors.append(np.linalg.norm(last + k * velocity - position(1, start + 7 + k)))
    assert scores["count"] == 24
    assert scores["ade"] == pytest.approx(np.mean(errors), rel=1e-5)
    final = [errors[11], errors[23]]
    assert scores["fde"] == pytest.approx(np.mean(final), rel=1e-5)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("110\t1\t2.0", "expected 4 fields 'frame ped x y', got 3"),
        ("110\t1\tabc\t2.0", "not a number"),
        ("110.5\t1\t1.0\t2.0", "frame id 110.5 is not an integer"),
        ("110\t1\tnan\t2.0", "non-finite value"),
        ("100\t1\t5.0\t5.0", "pedestrian 1 appears twice in frame 100"),
        ("105\t2\t5.0\t5.0", "frame 105 is off the file's frame grid"),
        ("1" + "0" * 22 + "\t1\t1.0\t2.0", "frame id 1" + "0" * 22 + " is beyond 2**53"),
    ],
)
def test_malformed_line_exits_2_naming_file_and_line(tmp_path: Path, line: str, message: str):
    make_scene(tmp_path / "raw")
    bad = tmp_path / "raw" / "hotel" / "test" / "d.txt"
    lines = bad.read_text().splitlines()
    lines.insert(2, line)  # becomes line 3
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    out.mkdir()
    result = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel")
    assert result.returncode == 2
    errors = result.stderr.strip().splitlines()
    assert len(errors) == 1 and "Traceback" not in result.stderr
    assert errors[0].startswith(f"error: {bad}:3: ") and message in errors[0]
    assert list(out.iterdir()) == []  # nothing written, no temporary file


def test_refuses_to_overwrite_and_writes_all_scenes_or_none(tmp_path: Path) -> None:
    make_scene(tmp_path / "raw")
    out = tmp_path / "out"
    out.mkdir()
    first = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel", *ANY)
    assert first.returncode == 0
    before = (out / "eth_ucy_hotel.h5").read_bytes()
    again = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel", *ANY)
    assert again.returncode == 2 and "already exists; pass --overwrite" in again.stderr
    assert (out / "eth_ucy_hotel.h5").read_bytes() == before
    forced = run_importer(
        "eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel", "--overwrite", *ANY
    )
    assert forced.returncode == 0
    # zara1 has no folder: the error names it and hotel is not written either
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    both = run_importer(
        "eth-ucy", tmp_path / "raw", "--out", fresh, "--scenes", "hotel", "zara1", *ANY
    )
    assert both.returncode == 2 and "zara1/train: missing folder" in both.stderr
    assert list(fresh.iterdir()) == []


def test_frame_step_is_the_most_common_gap() -> None:
    def tracks(frames: list[int]) -> Tracks:
        frames_array = np.array(frames)
        return Tracks("f.txt", np.arange(1, len(frames) + 1), frames_array, frames_array * 0, None)

    assert frame_step(tracks([0, 10, 20, 40, 50])) == 10  # a missing frame is a gap of two
    assert frame_step(tracks([780, 786, 792])) == 6
    assert frame_step(tracks([5])) == 0
    with pytest.raises(ImportDataError, match="f.txt:3: frame 25 is off"):
        frame_step(tracks([0, 10, 25, 30, 40]))


def test_single_pedestrian_windows_train_and_evaluate(tmp_path: Path) -> None:
    """A split whose windows hold one pedestrian each (one agent slot) is padded to two slots
    when loaded (the model has no edge between fewer), and scores the same pedestrians."""
    raw = tmp_path / "raw"
    for split, ped in (("train", 1), ("val", 2), ("test", 3)):
        write_file(raw / "hotel" / split / "a.txt", rows(ped, range(22)))
    config = EthUcyConfig(scenes=("hotel",), min_focal_agents=1)
    (path,) = import_eth_ucy(raw, tmp_path, config, False)
    assert read_dataset(path)[1]["train"].num_agents == 1
    dataset = TrajectoryDataset(path, "train")
    assert dataset.all().num_agents == 2 and not dataset.all().valid[:, :, 1].any()
    assert not dataset.data.focal[:, 1].any()
    model_cfg, train_cfg = make_configs("ours", epochs=1, batch_size=2, preset="paper")
    train(path, model_cfg, train_cfg, tmp_path / "run", progress=False)
    scores = evaluate_run(tmp_path / "run", path, "test").scores["main_agents"]["overall"]
    assert scores["count"] == 3 * 12 and scores["ade"] is not None  # 3 windows, 12 steps


# ---------------------------------------------------------------------------------------------
# INTERACTION track CSVs

HEADER = "case_id,track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width"


def interaction_rows(case: int, heading: bool = False) -> list[str]:
    """One sequence, frames 1..110 (0.1 s): track 1 (a car) at every frame, track 2 (a
    pedestrian) at frames 6..105 (100 frames). Windows of 100 frames every 10: starts 1 and 11,
    each with track 1 focal and track 2 present but not at every frame. x encodes the case."""
    out = []
    for frame in range(1, 111):
        tracks = [(1, "car")] + ([(2, "pedestrian/bicycle")] if 6 <= frame <= 105 else [])
        for track, kind in tracks:
            x, y = 1000.0 * case + 0.5 * frame, 3.0 * track
            psi = "0.1" if heading or kind == "car" else ""
            size = "4.0,1.8" if kind == "car" else ","
            fields = [str(track), str(frame), str(frame * 100), kind, f"{x}", f"{y}", "5", "0"]
            row = ",".join([*fields, psi, size])
            out.append(f"{case},{row}")
    return out


def write_interaction(folder: Path, heading: bool = False) -> None:
    """10 sequences: a.csv with case 0 (x ~ 0) and b.csv with cases 1..9. (A file without
    case_id is a continuous recording: test_import_interaction_recordings.py.)"""
    folder.mkdir(parents=True, exist_ok=True)
    a = interaction_rows(0, heading=heading)
    (folder / "a.csv").write_text("\n".join([HEADER, *a]) + "\n")
    b = [row for case in range(1, 10) for row in interaction_rows(case, heading=heading)]
    (folder / "b.csv").write_text("\n".join([HEADER, *b]) + "\n")


def test_interaction_split_by_sequence_80_10_10(tmp_path: Path) -> None:
    write_interaction(tmp_path / "raw")
    out = tmp_path / "inter.h5"
    result = run_importer("interaction", tmp_path / "raw", "--out", out)
    assert result.returncode == 0, result.stderr
    meta, splits = read_dataset(out)
    assert (meta.dt, meta.num_observed, meta.num_predicted) == (0.1, 40, 60)
    assert meta.state_names == ("x", "y", "vx", "vy")  # pedestrians have no psi_rad
    assert meta.role_names == ("car", "pedestrian/bicycle") and meta.recorded == ("roles",)
    assert [splits[s].n for s in SPLITS] == [16, 2, 2]  # 8, 1, 1 sequences of 2 windows
    seen = {}
    for split, data in splits.items():
        assert data.focal.tolist() == [[True, False]] * data.n
        assert data.roles.tolist() == [[0, 1]] * data.n
        starts = data.states[:, 0, 0, 0] % 1000  # 0.5 * first frame: windows at 1 and 11
        assert sorted(starts.tolist()) == sorted([0.5, 5.5] * (data.n // 2))
        for case in np.round(data.states[:, 0, 0, 0] // 1000).astype(int).tolist():
            assert seen.setdefault(case, split) == split  # a sequence in one split only
        # track 2 enters at frame 6: in the window starting at frame 1, from its 6th step
        first = data.states[:, 0, 0, 0] % 1000 == 0.5
        assert (data.valid[first, :, 1] == (np.arange(100) >= 5)).all()
    assert sorted(seen) == list(range(10))
    listing = {s["sequence"]: s["split"] for s in meta.config["sequences"]}
    assert len(listing) == 10 and sorted(listing.values()).count("train") == 8


def test_interaction_heading_channel_when_every_row_has_one(tmp_path: Path) -> None:
    write_interaction(tmp_path / "raw", heading=True)
    out = tmp_path / "inter.h5"
    import_interaction([tmp_path / "raw"], out, InteractionConfig(), overwrite=False)
    meta, splits = read_dataset(out)
    assert meta.state_names == ("x", "y", "vx", "vy", "heading")
    assert np.allclose(splits["train"].states[..., 4][splits["train"].valid], 0.1)


@pytest.mark.parametrize(
    ("edit", "where", "message"),
    [
        (lambda lines: lines.insert(3, "1,2,3"), ":4: ", "3 fields, the header names 12"),
        (lambda lines: lines.__setitem__(0, "track_id,frame_id"), ":1: ", "missing column(s)"),
        (
            lambda lines: lines.__setitem__(4, lines[4].replace(",car,", ",,")),
            ":5: ",
            "empty agent_type",
        ),
        (
            lambda lines: lines.__setitem__(1, lines[1].replace("1000.5", "x")),
            ":2: ",
            "x 'x' is not a number",
        ),
        (
            lambda lines: lines.__setitem__(5, lines[5].replace(",500,", ",550,")),
            ":6: ",
            "timestamp_ms 550 is not 0.1 s",
        ),
        (
            lambda lines: lines.__setitem__(2, "1" + "0" * 22 + "," + lines[2].split(",", 1)[1]),
            ":3: ",
            "case_id '1" + "0" * 22 + "' is beyond 2**53",
        ),
    ],
)
def test_interaction_malformed_input_exits_2_naming_the_line(tmp_path, edit, where, message):
    write_interaction(tmp_path / "raw")
    bad = tmp_path / "raw" / "b.csv"
    lines = bad.read_text().splitlines()
    edit(lines)
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out" / "inter.h5"
    out.parent.mkdir()
    result = run_importer("interaction", tmp_path / "raw", "--out", out)
    assert result.returncode == 2
    errors = result.stderr.strip().splitlines()
    assert len(errors) == 1 and errors[0].startswith(f"error: {bad}{where}"), errors
    assert message in errors[0]
    assert list(out.parent.iterdir()) == []


def test_interaction_refuses_a_file_named_twice(tmp_path: Path) -> None:
    write_interaction(tmp_path / "raw")
    again = tmp_path / "raw" / "b.csv"
    out = tmp_path / "inter.h5"
    result = run_importer("interaction", tmp_path / "raw", again, "--out", out)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"error: {again}: given twice (also as {again}); name each file once"
    ]
    assert not out.exists()


def test_interaction_reads_a_csv_with_a_byte_order_mark(tmp_path: Path) -> None:
    write_interaction(tmp_path / "raw")
    plain = tmp_path / "plain.h5"
    import_interaction([tmp_path / "raw"], plain, InteractionConfig(), overwrite=False)
    for name in ("a.csv", "b.csv"):  # as a spreadsheet's "CSV UTF-8" export writes them
        path = tmp_path / "raw" / name
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    marked = tmp_path / "marked.h5"
    import_interaction([tmp_path / "raw"], marked, InteractionConfig(), overwrite=False)
    for split in SPLITS:
        a, b = read_split(plain, split), read_split(marked, split)
        np.testing.assert_array_equal(a.states, b.states)
        np.testing.assert_array_equal(a.valid, b.valid)


def test_missing_output_folders_are_created(tmp_path: Path) -> None:
    make_scene(tmp_path / "raw")
    out = tmp_path / "new" / "data"
    result = run_importer("eth-ucy", tmp_path / "raw", "--out", out, "--scenes", "hotel", *ANY)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["eth_ucy_hotel.h5"]
    write_interaction(tmp_path / "csv")
    below_a_file = tmp_path / "new" / "data" / "eth_ucy_hotel.h5" / "x.h5"
    refused = run_importer("interaction", tmp_path / "csv", "--out", below_a_file)
    assert refused.returncode == 2 and "is not a directory" in refused.stderr


def test_an_empty_split_is_refused_naming_it_and_nothing_is_written(tmp_path: Path) -> None:
    raw, out = tmp_path / "raw", tmp_path / "out"
    make_scene(raw)  # hotel: under the default rule only train's window at g = 2 is kept
    make_pairs_scene(raw)  # zara1 imports, but is not written either
    result = run_importer("eth-ucy", raw, "--out", out, "--scenes", "zara1", "hotel")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"error: eth_ucy_hotel.h5: the val split would be empty: no window of {raw}/hotel/val/"
        "*.txt has 2 pedestrian(s) present at all 20 frames; lower --min-focal-agents "
        "(min_focal_agents, now 2)"
    ]
    assert not out.exists()
    (raw / "hotel" / "test" / "d.txt").unlink()  # an empty folder: the old rule fails too
    result = run_importer("eth-ucy", raw, "--out", out, "--scenes", "hotel", *ANY)
    assert result.returncode == 2 and not out.exists()
    assert result.stderr.strip().splitlines() == [
        f"error: eth_ucy_hotel.h5: the test split would be empty: {raw}/hotel/test holds no "
        ".txt file; add that split's files"
    ]
    write_file(raw / "hotel" / "test" / "d.txt", rows(1, range(19)))  # 19 frames: no window
    with pytest.raises(ImportDataError, match="test split would be empty: .* add longer ones$"):
        import_eth_ucy(raw, out, EthUcyConfig(scenes=("hotel",), min_focal_agents=1), False)
    assert not out.exists()


def test_interaction_empty_split_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "raw"
    folder.mkdir()
    rows_ = [row for case in (1, 2, 3) for row in interaction_rows(case)]  # 2 / 0 / 1 sequences
    (folder / "b.csv").write_text("\n".join([HEADER, *rows_]) + "\n")
    out = tmp_path / "inter.h5"
    result = run_importer("interaction", folder, "--out", out)
    assert result.returncode == 2 and not out.exists()
    assert result.stderr.strip().splitlines() == [
        "error: inter.h5: the val split would be empty: the split by sequence (0.8 / 0.1 / rest) "
        "gives it none of 3 sequence(s); import more sequences"
    ]
