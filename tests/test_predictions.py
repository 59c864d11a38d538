"""predictor.predictions: the one predictions record and its versioned file."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from conftest import make_predictions, make_trajectory_set

from predictor.predictions import (
    PREDICTIONS_FORMAT,
    PREDICTIONS_VERSION,
    Predictions,
    PredictionsError,
    load_predictions,
)


def assert_same(actual: Predictions, expected: Predictions) -> None:
    for f in fields(Predictions):
        got, want = getattr(actual, f.name), getattr(expected, f.name)
        if isinstance(want, np.ndarray):
            assert got.dtype == want.dtype, f.name
            np.testing.assert_array_equal(got, want, err_msg=f.name)
        else:
            assert got == want, f.name


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    pred = make_predictions(n=3)
    pred.save(tmp_path / "p.npz")
    loaded = load_predictions(tmp_path / "p.npz")
    assert_same(loaded, pred)
    assert (loaded.predictor, loaded.scenario, loaded.split) == ("ours", "unit_test", "test")
    with np.load(tmp_path / "p.npz") as npz:
        assert str(npz["format"]) == PREDICTIONS_FORMAT
        assert int(npz["version"]) == PREDICTIONS_VERSION


def test_from_split_takes_the_truth_from_the_split() -> None:
    data = make_trajectory_set(2, 10, 4, seed=3)
    pred = make_predictions(n=2, seed=3)
    np.testing.assert_array_equal(pred.true_xy, data.states[..., :2])
    np.testing.assert_array_equal(pred.attention_label, data.attention)
    np.testing.assert_array_equal(pred.scene, [0, 1])


def test_select_keeps_the_rows_in_the_split(tmp_path: Path) -> None:
    pred = make_predictions(n=4)
    subset = pred.select([3, 1])
    np.testing.assert_array_equal(subset.scene, [3, 1])
    np.testing.assert_array_equal(subset.pred_mean, pred.pred_mean[[3, 1]])
    np.testing.assert_array_equal(subset.true_xy[1], pred.true_xy[1])
    subset.save(tmp_path / "s.npz")
    assert_same(load_predictions(tmp_path / "s.npz"), subset)
    with pytest.raises(PredictionsError, match=r"scene rows must be in \[0, 3\]"):
        pred.select([4])


def test_inconsistent_arrays_are_refused() -> None:
    pred = make_predictions(n=2)
    values = {f.name: getattr(pred, f.name) for f in fields(Predictions)}
    with pytest.raises(PredictionsError, match="pred_mean has shape"):
        Predictions(**{**values, "pred_mean": pred.pred_mean[:, 1:]})
    with pytest.raises(PredictionsError, match="roles must index"):
        Predictions(**{**values, "roles": np.full_like(pred.roles, 3)})
    with pytest.raises(PredictionsError, match="num_observed=10 does not fit"):
        Predictions(**{**values, "num_observed": 10})


def test_version_2_file_reads_with_the_first_two_slots_focal(tmp_path: Path) -> None:
    pred = make_predictions(n=3, num_agents=5)
    pred.save(tmp_path / "p.npz")
    arrays = {k: v for k, v in np.load(tmp_path / "p.npz").items() if k != "focal"}
    np.savez(tmp_path / "v2.npz", **{**arrays, "version": np.int64(2)})
    loaded = load_predictions(tmp_path / "v2.npz")
    assert loaded.focal.tolist() == [[True, True, False, False, False]] * 3
    np.testing.assert_array_equal(loaded.pred_mean, pred.pred_mean)


def test_load_rejects_bad_files(tmp_path: Path) -> None:
    make_predictions().save(tmp_path / "p.npz")
    arrays = dict(np.load(tmp_path / "p.npz"))
    cases = {
        "missing.npz": (
            {k: v for k, v in arrays.items() if k != "roles"},
            r"missing arrays \['roles'\]",
        ),
        "shape.npz": ({**arrays, "valid": arrays["valid"][:, :-1]}, "valid has shape"),
        "v1.npz": (
            {k: v for k, v in arrays.items() if k not in ("format", "version")},
            "no format tag; files from before version 2",
        ),
        "v5.npz": ({**arrays, "version": np.int64(5)}, "version 5 is not supported"),
        "foreign.npz": ({**arrays, "format": np.str_("other")}, "not a smooth-attention-pred"),
    }
    for name, (content, message) in cases.items():
        np.savez(tmp_path / name, **content)
        with pytest.raises(PredictionsError, match=message) as info:
            load_predictions(tmp_path / name)
        assert str(info.value).startswith(str(tmp_path / name)) and "\n" not in str(info.value)
    (tmp_path / "text.npz").write_text("nope")
    with pytest.raises(PredictionsError, match="not an .npz file"):
        load_predictions(tmp_path / "text.npz")
    with pytest.raises(PredictionsError, match="no such file"):
        load_predictions(tmp_path / "absent.npz")
