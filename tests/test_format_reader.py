"""Tests for trajectory_data.reader: files that do not follow the contract, summaries,
tools/inspect_data.py, and the schema versions (1 still reads; 2 with optional data)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import (
    assert_sets_equal,
    downgrade_to_schema_1,
    one_line,
    run_tool,
    write_small_dataset,
)

from trajectory_data.format import (
    OPTIONAL_FIELDS,
    SPLITS,
    DatasetMeta,
    FormatError,
    TrajectorySet,
    write_dataset,
)
from trajectory_data.reader import read_dataset, read_meta, read_split, summarize

# ---------------------------------------------------------------------------------------------
# Reading: rejection of files that do not follow the contract


def test_missing_file_and_non_hdf5_rejected(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="no such file") as err:
        read_meta(tmp_path / "absent.h5")
    assert "absent.h5" in one_line(err)
    text = tmp_path / "notes.h5"
    text.write_text("hello, I am not HDF5\n")
    with pytest.raises(FormatError, match="not an HDF5 file") as err:
        read_dataset(text)
    assert "notes.h5" in one_line(err)


def test_foreign_hdf5_rejected(tmp_path: Path) -> None:
    path = tmp_path / "foreign.h5"
    with h5py.File(path, "w") as file:
        file.create_dataset("images", data=np.zeros((2, 3)))
        file.attrs["creator"] = "someone else"
    with pytest.raises(FormatError, match="no 'format' attribute") as err:
        read_split(path, "train")
    assert str(path) in one_line(err)


def _edit(path: Path, edit) -> None:
    with h5py.File(path, "r+") as file:
        edit(file)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda f: f.attrs.__setitem__("schema_version", 5), "schema_version 5 is not supported"),
        # schema 3 is an index of shards (tests/test_shards.py): it needs the list of them
        (
            lambda f: f.attrs.__setitem__("schema_version", 3),
            r"missing root attribute\(s\) \['shards'\]",
        ),
        (lambda f: f.attrs.__setitem__("format", "other"), "format is 'other'"),
        (lambda f: f.attrs.__delitem__("dt"), r"missing root attribute\(s\) \['dt'\]"),
        (lambda f: f.attrs.__setitem__("num_predicted", 3), "T=10 but num_observed"),
        (lambda f: f.attrs.__setitem__("case_names", "not json"), "not valid JSON"),
        (lambda f: f.attrs.__setitem__("role_names", '["a"]'), "roles index 2 out of range"),
        (lambda f: f.__delitem__("val"), "missing group 'val'"),
        (lambda f: f["test"].__delitem__("valid"), "split 'test': missing dataset 'valid'"),
        (lambda f: f["train"].attrs.__setitem__("count", 99), "count=99"),
    ],
)
def test_edited_file_rejected(dataset_file: Path, edit, message: str) -> None:
    _edit(dataset_file, edit)
    with pytest.raises(FormatError, match=message) as err:
        read_dataset(dataset_file)
    assert str(dataset_file) in one_line(err)


def test_wrong_dtype_and_shape_in_file_rejected(dataset_file: Path) -> None:
    def retype(file):
        states = file["train/states"][()]
        del file["train/states"]
        file["train"].create_dataset("states", data=states.astype(np.float64))

    _edit(dataset_file, retype)
    with pytest.raises(FormatError, match="states has dtype float64, expected float32"):
        read_split(dataset_file, "train")

    def reshape(file):
        del file["val/case"]
        file["val"].create_dataset("case", data=np.zeros(5, dtype=np.int8))

    _edit(dataset_file, reshape)
    with pytest.raises(FormatError, match="split 'val': case has shape"):
        read_split(dataset_file, "val")


@pytest.mark.parametrize("fraction", [0.1, 0.5, 0.9])
def test_truncated_file_rejected(dataset_file: Path, fraction: float) -> None:
    data = dataset_file.read_bytes()
    dataset_file.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(FormatError) as err:
        read_dataset(dataset_file)
    assert str(dataset_file) in one_line(err)


# ---------------------------------------------------------------------------------------------
# Summary


def test_summarize_reports_counts_per_split_and_case(dataset_file: Path) -> None:
    text = summarize(dataset_file)
    lines = text.splitlines()
    # counts (6, 3, 4) with alternating cases: major gets ceil(n/2), minor floor(n/2)
    expected = {"train": (3, 3, 6), "val": (2, 1, 3), "test": (2, 2, 4)}
    for split, counts in expected.items():
        row = next(line for line in lines if line.startswith(split))
        assert [int(v) for v in row.split()[1:4]] == list(counts)
    assert "T=10 (observed 4 + predicted 6)" in text
    assert "dt=0.1 s" in text
    assert "N=4" in text
    assert "unit_test" in text


# ---------------------------------------------------------------------------------------------
# tools/inspect_data.py


def _inspect(*args: object) -> subprocess.CompletedProcess:
    return run_tool("inspect_data.py", *args)


def test_inspect_tool_accepts_valid_file(dataset_file: Path) -> None:
    result = _inspect(dataset_file)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines()[-1] == (
        f"OK: {dataset_file} is a valid schema v2 dataset"
    )
    assert summarize(dataset_file) in result.stdout


@pytest.mark.parametrize("damage", ["truncate", "foreign", "schema"])
def test_inspect_tool_rejects_invalid_file_with_exit_2(dataset_file: Path, damage: str) -> None:
    if damage == "truncate":
        dataset_file.write_bytes(dataset_file.read_bytes()[:3000])
    elif damage == "foreign":
        _edit(dataset_file, lambda f: f.attrs.__delitem__("format"))
    else:
        _edit(dataset_file, lambda f: f.attrs.__setitem__("schema_version", 7))
    result = _inspect(dataset_file)
    assert result.returncode == 2  # an input error, as in every tool that reads the file
    assert result.stdout == "" and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {dataset_file}: ")


def test_inspect_tool_usage_errors_exit_2(tmp_path: Path) -> None:
    for args in ([tmp_path / "absent.h5"], [], ["a.h5", "b.h5"]):
        result = _inspect(*args)
        assert result.returncode == 2
        assert "Traceback" not in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1


# ---------------------------------------------------------------------------------------------
# Schema 2: optional data, focal mask; schema 1 still reads


def test_schema_1_file_reads_with_the_first_two_slots_focal(tmp_path: Path) -> None:
    path = tmp_path / "v1.h5"
    meta, splits = write_small_dataset(path, counts=(4, 2, 3), num_agents=5)
    downgrade_to_schema_1(path)
    with h5py.File(path, "r") as file:  # really the schema-1 layout now
        assert int(file.attrs["schema_version"]) == 1 and "focal" not in file["train"]
    read_back_meta, read_back = read_dataset(path)
    assert read_back_meta.schema_version == 1
    assert read_back_meta.recorded == OPTIONAL_FIELDS
    assert read_back_meta.state_names == ("x", "y", "heading", "speed")
    for name in SPLITS:
        assert_sets_equal(read_back[name], splits[name])  # every array, focal included
        expected = np.zeros((splits[name].n, 5), bool)
        expected[:, :2] = True
        np.testing.assert_array_equal(read_back[name].focal, expected)


def _positions_only_meta(**changes) -> DatasetMeta:
    fields = {
        "scenario": "walkers",
        "dt": 0.4,
        "num_observed": 2,
        "num_predicted": 3,
        "case_names": ("all",),
        "major_case": "",
        "role_names": ("pedestrian",),
        "state_names": ("x", "y"),
        "action_names": (),
        "recorded": (),
    }
    return DatasetMeta(**{**fields, **changes})


def _positions_only_set(n: int = 3, agents: int = 4) -> TrajectorySet:
    rng = np.random.default_rng(3)
    empty = TrajectorySet.empty(5, agents, num_states=2, num_actions=0)
    arrays = {
        name: np.zeros((n, *array.shape[1:]), array.dtype) for name, array in empty.arrays().items()
    }
    arrays["states"] = rng.normal(size=(n, 5, agents, 2)).astype(np.float32)
    arrays["valid"][:] = True
    arrays["attention"][:] = -1
    arrays["seed"][:] = -1
    arrays["focal"][:, [1, 3]] = True
    return TrajectorySet(**arrays)


def test_positions_only_file_stores_only_required_data_and_reads_neutral_values(
    tmp_path: Path,
) -> None:
    meta, data = _positions_only_meta(), _positions_only_set()
    path = write_dataset(tmp_path / "walk.h5", meta, {"train": data})
    with h5py.File(path, "r") as file:
        assert sorted(file["train"]) == ["focal", "states", "valid"]
        assert json.loads(file.attrs["recorded"]) == []
    read_back_meta, splits = read_dataset(path)
    assert read_back_meta == meta and not read_back_meta.has("attention")
    assert_sets_equal(splits["train"], data)
    assert (splits["train"].attention == -1).all() and (splits["train"].seed == -1).all()
    assert splits["train"].actions.shape == (3, 5, 4, 0)
    assert "focal/window" in summarize(path)


def test_schema_2_rejects_unlisted_data_and_bad_channels(tmp_path: Path) -> None:
    data = _positions_only_set()
    labelled = dataclasses.replace(data, attention=np.zeros_like(data.attention))
    with pytest.raises(FormatError, match="attention holds data but the metadata does not list"):
        write_dataset(tmp_path / "a.h5", _positions_only_meta(), {"train": labelled})
    with pytest.raises(FormatError, match=r"state_names must start with \['x', 'y'\]"):
        _positions_only_meta(state_names=("y", "x")).validate()
    with pytest.raises(FormatError, match="recorded names unknown datasets"):
        _positions_only_meta(recorded=("labels",)).validate()
    with pytest.raises(FormatError, match="states has 2 channels but state_names lists 3"):
        data.validate(_positions_only_meta(state_names=("x", "y", "heading")))
    path = write_dataset(tmp_path / "b.h5", _positions_only_meta(), {"train": data})
    _edit(path, lambda f: f["val"].create_dataset("roles", data=np.zeros((0, 4), np.int8)))
    with pytest.raises(FormatError, match="split 'val': holds \\['roles'\\] that the root") as err:
        read_dataset(path)
    assert str(path) in one_line(err)
