"""Tests for trajectory_data.format: round trip, atomic writes, and rejection of invalid arrays and
meta before anything is written."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import (
    assert_sets_equal,
    make_meta,
    make_trajectory_set,
    tool_env,
    write_small_dataset,
)

import trajectory_data.format as fmt
from trajectory_data.format import (
    OPTIONAL_FIELDS,
    SPLITS,
    FormatError,
    TrajectorySet,
    write_dataset,
)
from trajectory_data.reader import read_dataset, read_meta, read_split

# ---------------------------------------------------------------------------------------------
# Round trip


def test_round_trip_keeps_every_array_dtype_and_meta(tmp_path: Path) -> None:
    path = tmp_path / "data.h5"
    meta, splits = write_small_dataset(path, counts=(6, 3, 4))
    read_back_meta, read_back = read_dataset(path)
    assert read_back_meta == meta
    assert read_back_meta.config == {
        "generator": {"seed": 7, "note": "made by tests/conftest.py"},
        "lanes": [1, 2],
    }
    assert read_back_meta.case_names == ("major", "minor")
    assert read_meta(path) == meta
    for name in SPLITS:
        assert_sets_equal(read_back[name], splits[name])
        assert_sets_equal(read_split(path, name), splits[name])


def test_file_layout_follows_contract(tmp_path: Path) -> None:
    path = tmp_path / "data.h5"
    meta, splits = write_small_dataset(path, counts=(5, 0, 2))
    with h5py.File(path, "r") as file:
        assert file.attrs["format"] == "smooth-attention-trajectories"
        assert int(file.attrs["schema_version"]) == 2
        assert file.attrs["state_names"] == '["x", "y", "heading", "speed"]'
        assert file.attrs["action_names"] == '["steering", "acceleration"]'
        assert json.loads(file.attrs["recorded"]) == list(OPTIONAL_FIELDS)
        assert file["train/focal"].dtype == np.bool_ and file["train/focal"].shape == (5, 4)
        assert int(file["train"].attrs["count"]) == 5
        assert int(file["val"].attrs["count"]) == 0
        states = file["train/states"]
        assert states.chunks == (1, meta.num_steps, 4, 4)
        assert states.compression == "gzip"
        assert file["val/states"].shape == (0, meta.num_steps, 4, 4)


def test_empty_and_missing_splits_round_trip(tmp_path: Path) -> None:
    meta = make_meta()
    train = make_trajectory_set(3, meta.num_steps, 5)
    path = write_dataset(
        tmp_path / "d.h5", meta, {"train": train, "val": TrajectorySet.empty(meta.num_steps, 5)}
    )
    _, splits = read_dataset(path)
    assert_sets_equal(splits["train"], train)
    for name in ("val", "test"):
        assert splits[name].n == 0
        assert splits[name].states.shape == (0, meta.num_steps, 5, 4)


def test_unknown_split_name_rejected(tmp_path: Path) -> None:
    meta = make_meta()
    with pytest.raises(FormatError, match="unknown split"):
        write_dataset(tmp_path / "d.h5", meta, {"training": make_trajectory_set(2, 10)})
    assert not (tmp_path / "d.h5").exists()
    write_small_dataset(tmp_path / "ok.h5")
    with pytest.raises(FormatError, match="unknown split 'dev'"):
        read_split(tmp_path / "ok.h5", "dev")


# ---------------------------------------------------------------------------------------------
# Writing: overwrite and atomicity


def test_refuses_to_overwrite_and_overwrites_when_asked(tmp_path: Path) -> None:
    path = tmp_path / "data.h5"
    write_small_dataset(path, counts=(2, 1, 1))
    before = path.read_bytes()
    meta = make_meta()
    new = {"train": make_trajectory_set(7, meta.num_steps, 3, seed=9)}
    with pytest.raises(FileExistsError, match="already exists"):
        write_dataset(path, meta, new)
    assert path.read_bytes() == before
    write_dataset(path, meta, new, overwrite=True)
    assert_sets_equal(read_split(path, "train"), new["train"])


@pytest.mark.parametrize("existing", [False, True])
def test_interrupted_write_leaves_nothing_behind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool
) -> None:
    path = tmp_path / "data.h5"
    if existing:
        write_small_dataset(path, counts=(2, 1, 1))
    before = sorted(p.name for p in tmp_path.iterdir())
    old_bytes = path.read_bytes() if existing else None
    real_write_split = fmt._write_split
    calls = []

    def interrupted(group, data, *rest):  # writes the first split, then "Ctrl-C" on the second
        calls.append(group.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real_write_split(group, data, *rest)

    monkeypatch.setattr(fmt, "_write_split", interrupted)
    meta = make_meta()
    with pytest.raises(KeyboardInterrupt):
        write_dataset(path, meta, {"train": make_trajectory_set(3, meta.num_steps)}, overwrite=True)
    assert len(calls) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no temp file left
    if existing:
        assert path.read_bytes() == old_bytes
    else:
        assert not path.exists()


def test_invalid_data_is_rejected_before_anything_is_written(tmp_path: Path) -> None:
    meta = make_meta()
    bad = make_trajectory_set(3, meta.num_steps)
    bad.attention[0, 0, 0] = 9
    with pytest.raises(FormatError, match="split 'train'.*attention"):
        write_dataset(tmp_path / "d.h5", meta, {"train": bad})
    assert list(tmp_path.iterdir()) == []


def test_invalid_meta_is_rejected(tmp_path: Path) -> None:
    meta = make_meta()
    data = {"train": make_trajectory_set(2, meta.num_steps)}
    cases = {
        "major_case": dataclasses.replace(meta, major_case="rare"),
        "dt": dataclasses.replace(meta, dt=0.0),
        "case_names": dataclasses.replace(meta, case_names=("a", "a")),
        "config": dataclasses.replace(meta, config={"x": object()}),
    }
    for what, bad_meta in cases.items():
        with pytest.raises(FormatError, match=what):
            write_dataset(tmp_path / "d.h5", bad_meta, data)
    with pytest.raises(FormatError, match="T=10"):
        write_dataset(tmp_path / "d.h5", dataclasses.replace(meta, num_predicted=2), data)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------------------------
# Validation of in-memory sets


def _replace(data: TrajectorySet, **arrays) -> TrajectorySet:
    return dataclasses.replace(data, **arrays)


def test_validation_catches_nan_where_valid_only() -> None:
    data = make_trajectory_set(3)
    invalid = np.argwhere(~data.valid)[0]
    states = data.states.copy()
    states[tuple(invalid)] = np.nan  # NaN in an absent agent: allowed
    _replace(data, states=states).validate(make_meta())
    states[1, 2, 0, 3] = np.inf  # agent 0 is always valid
    with pytest.raises(FormatError, match="states are not finite where valid"):
        _replace(data, states=states).validate(make_meta(), source="x")


@pytest.mark.parametrize("label", [-2, 4, 100])
def test_validation_catches_out_of_range_attention(label: int) -> None:
    data = make_trajectory_set(3, num_agents=4)
    attention = data.attention.copy()
    attention[2, 5, 3] = label
    with pytest.raises(FormatError, match=f"found {label}"):
        _replace(data, attention=attention).validate()


def test_validation_catches_bad_shapes_dtypes_and_indices() -> None:
    data = make_trajectory_set(3, num_steps=10, num_agents=4)
    meta = make_meta()
    bad = {
        "actions has 3 channels": _replace(data, actions=np.zeros((3, 10, 4, 3), np.float32)),
        "valid has shape .* inconsistent with T=10": _replace(data, valid=data.valid[:, :9]),
        "roles has shape": _replace(data, roles=data.roles[:, None]),
        "seed has dtype int32": _replace(data, seed=data.seed.astype(np.int32)),
        "case must be a numpy array": _replace(data, case=[0, 1, 0]),
        "case index 2 out of range": _replace(data, case=np.array([0, 2, 1], np.int8)),
        "roles has negative index": _replace(data, roles=-data.roles),
    }
    for message, bad_data in bad.items():
        with pytest.raises(FormatError, match=message):
            bad_data.validate(meta)
    with pytest.raises(FormatError, match="T=10 but"):
        data.validate(make_meta(num_observed=2))


# ---------------------------------------------------------------------------------------------
# Set operations


def test_subset_and_select_case() -> None:
    data = make_trajectory_set(5)
    picked = data.subset([4, 1])
    np.testing.assert_array_equal(picked.seed, data.seed[[4, 1]])
    np.testing.assert_array_equal(picked.states[0], data.states[4])
    minor = data.select_case(1)
    assert minor.n == 2  # cases alternate 0, 1, 0, 1, 0
    np.testing.assert_array_equal(minor.seed, data.seed[[1, 3]])
    assert (minor.case == 1).all()
    minor.validate(make_meta())


def test_concatenate_pads_missing_agents_as_invalid() -> None:
    small = make_trajectory_set(2, num_agents=3, seed=1)
    large = make_trajectory_set(3, num_agents=5, seed=2)
    both = TrajectorySet.concatenate([small, large])
    both.validate(make_meta())
    assert (both.n, both.num_steps, both.num_agents) == (5, 10, 5)
    np.testing.assert_array_equal(both.states[:2, :, :3], small.states)
    np.testing.assert_array_equal(both.attention[:2, :, :3], small.attention)
    assert not both.valid[:2, :, 3:].any()
    assert (both.states[:2, :, 3:] == 0).all() and (both.actions[:2, :, 3:] == 0).all()
    assert (both.attention[:2, :, 3:] == -1).all()
    np.testing.assert_array_equal(both.roles[:2, :3], small.roles)
    assert_sets_equal(both.subset(slice(2, 5)), large)
    np.testing.assert_array_equal(both.seed, np.concatenate([small.seed, large.seed]))
    with pytest.raises(FormatError, match="different T"):
        TrajectorySet.concatenate([small, make_trajectory_set(2, num_steps=8)])


def test_empty_set_is_valid() -> None:
    empty = TrajectorySet.empty(10, 6)
    assert (empty.n, empty.num_steps, empty.num_agents) == (0, 10, 6)
    empty.validate(make_meta())
    assert TrajectorySet.concatenate([empty, make_trajectory_set(2, num_agents=4)]).n == 2


# ---------------------------------------------------------------------------------------------
# Import hygiene


def test_format_module_does_not_import_torch() -> None:
    code = "import sys, trajectory_data.format; print('torch' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=tool_env(), check=True
    )
    assert out.stdout.strip() == "False"
