"""Storage of the influence per time window (`influence_windows`, schema 4): generation against
`windowed_influence`, the file round trip with its window length, validation on load, the
generator's and CLI's refusals, and the per-window summary of inspect_data.py against a
hand-built set."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
from conftest import make_meta, make_trajectory_set, run_tool

import scenarios
from pipeline.generation import GenerateConfig, generate_dataset, plan, slot_windowed_influence
from scenarios.counterfactual import windowed_influence
from trajectory_data.format import INFLUENCE, INFLUENCE_WINDOWS, FormatError, write_dataset
from trajectory_data.reader import read_dataset, read_meta
from trajectory_data.window_summary import influence_moves, influence_window_rows

SMALL = {"num_major": 3, "num_minor": 1, "num_test": 1}


def test_generated_windows_equal_windowed_influence(tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v3", **SMALL)
    plain = generate_dataset(config, tmp_path / "plain.h5", progress=False)
    result = generate_dataset(config, tmp_path / "w.h5", progress=False, influence_window_steps=16)
    meta, splits = read_dataset(result.path)
    assert meta.schema_version == 4 and meta.has(INFLUENCE_WINDOWS) and not meta.has(INFLUENCE)
    assert meta.influence_window_steps == 16 and meta.num_influence_windows == 3  # 48 steps
    _, plain_splits = read_dataset(plain.path)
    scenario = scenarios.make("halting_car_v3")
    for name, data in splits.items():
        assert data.influence is None and plain_splits[name].influence_windows is None
        np.testing.assert_array_equal(data.states, plain_splits[name].states)
        plans = [scenario.plan(int(s), meta.case_names[c]) for s, c in zip(data.seed, data.case)]
        np.testing.assert_array_equal(
            data.influence_windows, windowed_influence(scenario, plans, 16)
        )
    with h5py.File(plain.path) as file:  # a file without them: schema 2, no attribute
        assert file.attrs["schema_version"] == 2 and "influence_window_steps" not in file.attrs


def test_windows_do_not_depend_on_the_batch():
    config = GenerateConfig.for_scenario("double_merge_v1", **SMALL)
    scenario = scenarios.make("double_merge_v1")
    slots = plan(config)
    one = slot_windowed_influence(scenario, slots, 9, batch_scenes=1)
    many = slot_windowed_influence(scenario, slots, 9, batch_scenes=64)
    assert one.shape == (len(slots), 5, 22, 22)  # 45 predicted steps
    np.testing.assert_array_equal(one, many)


def test_generator_refuses_bad_window_lengths(tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v3", **SMALL)
    for bad, message in ((-1, "at least 0"), (True, "an integer"), (2.0, "an integer")):
        with pytest.raises(ValueError, match=f"influence_window_steps must be {message}"):
            generate_dataset(config, tmp_path / "x.h5", progress=False, influence_window_steps=bad)
    with pytest.raises(ValueError, match="single files only"):
        generate_dataset(
            config, tmp_path / "shards", progress=False, influence_window_steps=4, shard_size=3
        )
    assert list(tmp_path.iterdir()) == []


# ---- the file ---------------------------------------------------------------------------------
def windows_meta(window_steps: int = 4, influence: bool = False):
    """make_meta (4 observed + 6 predicted steps) recording influence_windows: W = 2."""
    base = make_meta()
    extra = (INFLUENCE, INFLUENCE_WINDOWS) if influence else (INFLUENCE_WINDOWS,)
    return dataclasses.replace(
        base, recorded=(*base.recorded, *extra), influence_window_steps=window_steps
    )


def windows_set(n: int = 3, agents: int = 4, seed: int = 1, windows: int = 2):
    data = make_trajectory_set(n, 10, agents, seed=seed)
    rng = np.random.default_rng(seed)
    matrices = rng.uniform(0, 5, (n, windows, agents, agents)).astype(np.float32)
    return dataclasses.replace(data, influence_windows=matrices)


def test_round_trip_subset_concatenate_and_padding(tmp_path):
    meta = windows_meta()
    both = dataclasses.replace(windows_set(3), influence=np.ones((3, 2, 4, 4), dtype=np.float32))
    splits = {"train": both, "test": windows_set(2, seed=2)}
    with pytest.raises(FormatError, match="does not list influence as recorded but the split"):
        write_dataset(tmp_path / "x.h5", meta, splits)
    meta = windows_meta(influence=True)
    splits["test"] = dataclasses.replace(
        splits["test"], influence=np.zeros((2, 2, 4, 4), np.float32)
    )
    path = write_dataset(tmp_path / "w.h5", meta, splits)
    read_back_meta, read_back = read_dataset(path)
    assert read_back_meta == dataclasses.replace(meta, schema_version=4)
    np.testing.assert_array_equal(read_back["train"].influence_windows, both.influence_windows)
    np.testing.assert_array_equal(read_back["train"].influence, both.influence)
    assert read_back["val"].influence_windows.shape == (0, 2, 4, 4)
    picked = read_back["train"].subset([2, 0])
    np.testing.assert_array_equal(picked.influence_windows, both.influence_windows[[2, 0]])
    wide = windows_set(1, agents=5, seed=3)
    joined = type(wide).concatenate([windows_set(3), wide])
    assert joined.influence_windows.shape == (4, 2, 5, 5)
    assert np.isnan(joined.influence_windows[:3, :, 4]).all()
    assert np.isnan(joined.influence_windows[:3, :, :, 4]).all()
    other_count = type(wide).concatenate([windows_set(1), windows_set(1, windows=3)])
    assert other_count.influence_windows is None  # windows of another length: not joined


def test_window_data_and_length_are_validated_on_load(tmp_path):
    meta = windows_meta()
    path = write_dataset(tmp_path / "w.h5", meta, {"train": windows_set(3)})
    bad = tmp_path / "bad.h5"

    def broken(edit) -> pytest.ExceptionInfo:
        bad.write_bytes(path.read_bytes())
        with h5py.File(bad, "r+") as file:
            edit(file)
        with pytest.raises(FormatError) as err:
            read_dataset(bad)
        return str(err.value)

    def replace(data):
        def edit(file):
            del file["train/influence_windows"]
            file["train"].create_dataset("influence_windows", data=data)

        return edit

    three = np.zeros((3, 3, 4, 4), np.float32)  # 3 windows, but 6 steps / 4 is 2
    assert "influence_windows has shape (3, 3, 4, 4), expected (3, 2, 4, 4)" in broken(
        replace(three)
    )
    assert "influence_windows is float64" in broken(replace(np.zeros((3, 2, 4, 4))))
    assert "missing dataset 'influence_windows'" in broken(
        lambda file: file["train"].__delitem__("influence_windows")
    )
    assert "influence_window_steps must be >= 1 where recorded lists" in broken(
        lambda file: file.attrs.__delitem__("influence_window_steps")
    )
    # a window length of 6 makes it one window: the stored two no longer fit
    assert "expected (3, 1, 4, 4)" in broken(
        lambda file: file.attrs.__setitem__("influence_window_steps", np.int64(6))
    )
    unlisted = tmp_path / "unlisted.h5"
    write_dataset(unlisted, make_meta(), {"train": make_trajectory_set(3, 10, 4)})
    with h5py.File(unlisted, "r+") as file:
        file["train"].create_dataset("influence_windows", data=np.zeros((3, 2, 4, 4), np.float32))
    with pytest.raises(FormatError, match="leaves out"):
        read_dataset(unlisted)
    with h5py.File(unlisted, "r+") as file:
        file.attrs["influence_window_steps"] = np.int64(4)
    with pytest.raises(FormatError, match="influence_window_steps must be >= 1 where"):
        read_meta(unlisted)
    negative = windows_set(3)
    negative.influence_windows[0, 1, 0, 1] = -1.0
    with pytest.raises(FormatError, match="influence_windows must be NaN or finite"):
        write_dataset(tmp_path / "y.h5", meta, {"train": negative})


# ---- the summary --------------------------------------------------------------------------------
def test_window_summary_by_hand():
    """Two windows (steps 4-6, 7-9). Scene 0: agent 0 attends to 1, then to 2; agent 1 to 0
    throughout. Scene 1: no labels, no influence."""
    meta = windows_meta(window_steps=3)
    data = windows_set(2, windows=2)
    attention = np.full((2, 10, 4), -1, dtype=np.int16)
    attention[0, 4:7, 0], attention[0, 7:, 0], attention[0, 4:, 1] = 1, 2, 0
    matrices = np.zeros((2, 2, 4, 4), np.float32)
    matrices[0, 0, 0] = [0, 2.0, 0.5, 0.1]
    matrices[0, 1, 0] = [0, 0.3, 1.5, 0.0]
    matrices[0, :, 1] = [1.0, 0, 0, 0]
    data = dataclasses.replace(data, attention=attention, influence_windows=matrices)
    first, second = influence_window_rows(meta, {"train": data})
    assert first["steps"] == (4, 7) and second["steps"] == (7, 10)
    assert first["pairs"] == 2 and first["labelled"] == pytest.approx(1.5)
    assert first["others"] == pytest.approx((0.5 + 0.1) / 4) and first["share_above"] == 1.0
    assert first["top_changed"] is None and first["label_changed"] is None
    assert second["labelled"] == pytest.approx(1.25)
    assert second["others"] == pytest.approx(0.3 / 4)
    # agent 0's top agent and label move from 1 to 2, agent 1's stay 0; scene 1 has none
    assert second["top_changed"] == 0.5 and second["label_changed"] == 0.5
    # every top agent is one the label names; agent 0's label names 2 agents and its top moves
    assert first["top_labelled"] == 1.0 and second["top_labelled"] == 1.0
    moves = influence_moves(meta, {"train": data})
    assert moves == {"moving": 1, "top_moves": 1.0, "top_moves_fixed": 0.0}
    other_case = int(1 - data.case[0])
    assert influence_moves(meta, {"train": data}, case=int(data.case[0])) == moves
    assert influence_moves(meta, {"train": data}, case=other_case)["moving"] == 0
    # agent 1's top becomes agent 3, which it does not attend to; a window without any
    # influence on agent 0 leaves its top agents {1} and breaks no count
    matrices[0, 1, 1] = [1.0, 0, 0, 2.0]
    matrices[0, 1, 0] = 0.0
    data = dataclasses.replace(data, influence_windows=matrices)
    first, second = influence_window_rows(meta, {"train": data})
    assert second["top_labelled"] == 0.0  # agent 1 only: agent 0 has no top agent
    assert second["top_changed"] == 1.0
    moves = influence_moves(meta, {"train": data})
    assert moves == {"moving": 1, "top_moves": 0.0, "top_moves_fixed": 1.0}


def test_cli_writes_windows_and_inspect_summarises_them(tmp_path):
    out = tmp_path / "w.h5"
    small = ("--num-major", "2", "--num-minor", "1", "--num-test", "1", "--no-progress")
    args = ("--scenario", "halting_car_v3", *small, "--influence-window-steps", "16")
    done = run_tool("generate.py", *args, "--out", out)
    assert done.returncode == 0, done.stderr
    assert read_meta(out).influence_window_steps == 16
    shown = run_tool("inspect_data.py", out)
    assert shown.returncode == 0, shown.stderr
    assert "influence per time window of 16 steps" in shown.stdout
    assert "\n2       44-59 " in shown.stdout  # the third window's row
    assert "moving labels (focal agents whose label names 2+ agents" in shown.stdout
    for extra, message in (
        (("--influence-window-steps", "-2"), "--influence-window-steps must be at least 1"),
        (("--influence-window-steps", "x"), "invalid int"),
        (
            ("--influence-window-steps", "4", "--shard-size", "2"),
            "--influence-window-steps is written to single files only",
        ),
    ):
        done = run_tool("generate.py", *small, *extra, "--out", tmp_path / "bad")
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1 and message in lines[0], done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.h5"]
