"""tools/evaluate.py (on conftest's `smoke` run): the JSON and predictions it writes, the
baselines, the library behind it, another scenario's data, and one-line errors of both tools."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, load_tool, refuse_writes_in, run_tool, tool_env
from test_training import write_braking_dataset

NPZ_KEYS = {
    "format",
    "version",
    "predictor",
    "scenario",
    "split",
    "scene",
    "pred_mean",
    "true_xy",
    "valid",
    "focal",
    "case",
    "case_names",
    "role_names",
    "roles",
    "attention",
    "attention_label",
    "interaction",
    "samples",
    "num_observed",
    "dt",
}


def test_evaluate_writes_json_and_predictions(smoke):
    evaluated = smoke["evaluated"]
    assert evaluated.returncode == 0, evaluated.stderr
    result = json.loads((smoke["run"] / "eval.json").read_text())
    assert result["predictor"] == "ours" and result["scenes"] == 4
    for group in ("main_agents", "all_agents"):
        assert result[group]["overall"]["ade"] > 0
        assert set(result[group]["cases"]) == {"early", "late"}
    assert 0 <= result["attention_accuracy"]["overall"]["accuracy"] <= 1
    with np.load(smoke["root"] / "pred.npz") as npz:
        assert set(npz.files) == NPZ_KEYS
        n, steps, agents = npz["true_xy"].shape[:3]
        assert (n, steps, agents) == (4, 12, 4)
        assert npz["pred_mean"].shape == (4, 7, 4, 2) and npz["pred_mean"].dtype == np.float32
        attention = npz["attention"]
        assert attention.shape == (4, 11, 4, 4) and attention.dtype == np.float32
        assert int(npz["num_observed"]) == 5 and float(npz["dt"]) == pytest.approx(0.2)
        # rows of present agents with present others sum to one
        present = npz["valid"][:, :-1]
        np.testing.assert_allclose(attention.sum(-1)[present], 1.0, atol=1e-5)
        assert list(npz["case_names"]) == ["early", "late"]


def test_const_vel_baseline_and_its_nan_attention(smoke, tmp_path: Path):
    out = run_tool(
        "evaluate.py",
        "--baseline",
        "const_vel",
        "--data",
        smoke["data"],
        "--out",
        tmp_path / "cv.json",
        "--save-predictions",
        tmp_path / "cv.npz",
    )
    assert out.returncode == 0, out.stderr
    result = json.loads((tmp_path / "cv.json").read_text())
    assert result["predictor"] == "const_vel"
    assert result["attention_accuracy"]["overall"]["accuracy"] is None
    with np.load(tmp_path / "cv.npz") as npz:
        assert np.isnan(npz["attention"]).all() and set(npz.files) == NPZ_KEYS


def test_ridge_baseline_is_fitted_on_the_train_split_and_matches_the_library(smoke, tmp_path):
    from predictor.evaluation import evaluate_baseline

    out = run_tool(
        "evaluate.py",
        "--baseline",
        "ridge_labelled",
        "--data",
        smoke["data"],
        "--out",
        tmp_path / "ridge.json",
        "--save-predictions",
        tmp_path / "ridge.npz",
    )
    assert out.returncode == 0, out.stderr
    result = json.loads((tmp_path / "ridge.json").read_text())
    assert result["predictor"] == "ridge_labelled" and result["scenes"] == 4
    fit = result["baseline_fit"]
    assert fit["fit_split"] == "train" and fit["fit_scenes"] == 6
    assert fit["history_steps"] == 4  # the default 12, capped at num_observed - 1
    assert set(fit["alpha"]) <= {"leader", "follower", "distractor"}
    library = evaluate_baseline("ridge_labelled", smoke["data"], "test")
    assert library.to_dict()["main_agents"] == result["main_agents"]
    with np.load(tmp_path / "ridge.npz") as npz:  # the same predictions in another process
        np.testing.assert_array_equal(npz["pred_mean"], library.predictions.pred_mean)
        assert np.isnan(npz["attention"]).all()


def test_closed_stdout_ends_quietly(smoke):
    """`evaluate.py ... | head -0`: the reader is gone before the table is written."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        out = subprocess.run(
            [
                sys.executable,
                str(REPO_ROOT / "tools" / "evaluate.py"),
                "--baseline",
                "const_vel",
                "--data",
                str(smoke["data"]),
            ],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            env=tool_env(),
            timeout=120,
        )
    finally:
        os.close(write_end)
    assert out.returncode == 1
    assert "Traceback" not in out.stderr and "BrokenPipe" not in out.stderr


@pytest.mark.parametrize(
    ("tool", "args", "message"),
    [
        ("train.py", ["--data", "{missing}", "--out", "{tmp}/r"], "does not exist"),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--variant", "bogus"],
            "invalid choice",
        ),
        ("train.py", ["--data", "{data}", "--out", "{tmp}/r", "--epochs", "-1"], "epochs"),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--epochs", "0"],
            "train.epochs must be >= 1, got 0",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}", "--resume"],
            "it has no last.pt",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{run}", "--resume", "--set", "train.lr=0.5"],
            "--set train.lr=0.5 differs from the stored run's --set train.lr=0.001 (a resumed",
        ),
        (
            "evaluate.py",
            ["--run", "{run}", "--data", "{other}", "--out", "{tmp}/e.json"],
            "was trained on data with dt 0.2, num_predicted 7, but",
        ),
        ("train.py", ["--data", "{foreign}", "--out", "{tmp}/r"], "not an HDF5 file"),
        ("train.py", ["--data", "{data}", "--out", "{run}"], "not empty"),
        ("train.py", ["--data", "{data}", "--out", "{tmp}/r", "--resume"], "does not exist"),
        ("evaluate.py", ["--run", "{run}", "--data", "{missing}"], "does not exist"),
        (
            "evaluate.py",
            ["--run", "{run}", "--data", "{foreign}", "--out", "{tmp}/e.json"],
            "not an HDF5 file",
        ),
        (
            "evaluate.py",
            ["--run", "{run}", "--data", "{data}"],
            "eval.json already exists; pass --overwrite to replace it, or --out FILE.json to "
            "write elsewhere",
        ),
        (
            "evaluate.py",
            ["--run", "{tmp}", "--data", "{data}", "--out", "{tmp}/e.json"],
            "checkpoint",
        ),
        ("evaluate.py", ["--baseline", "magic", "--data", "{data}"], "invalid choice"),
        ("evaluate.py", ["--run", "{foreign}", "--data", "{data}"], "is not a directory"),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "model.neighbours=grid"],
            "model.neighbours must be one of all, radius, knn, got 'grid'",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "model.neighbour_radius_m=0"],
            "model.neighbour_radius_m must be > 0, got 0.0",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "model.neighbour_k=0"],
            "model.neighbour_k must be >= 1, got 0",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "model.neighbour_k=2.5"],
            "model.neighbour_k takes an integer, got '2.5'",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "model.neighbour=knn"],
            "unknown setting 'model.neighbour' (did you mean model.neighbours?); model settings: ",
        ),
        (
            "train.py",
            ["--data", "{data}", "--out", "{tmp}/r", "--set", "train.epochs=3"],
            "train.epochs is not set with --set: use --epochs",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(smoke, tmp_path, capsys, tool, args, message):
    foreign = tmp_path / "foreign.h5"
    foreign.write_text("not a dataset")
    other = tmp_path / "other_dt.h5"  # same scenario, another dt and horizon
    write_other_dataset(other)
    names = {
        "other": other,
        "missing": tmp_path / "missing.h5",
        "tmp": tmp_path,
        "data": smoke["data"],
        "foreign": foreign,
        "run": smoke["run"],
    }
    argv = [a.format(**names) for a in args]
    module = load_tool(tool)
    with pytest.raises(SystemExit) as exit_info:
        module.main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error:") and message in err, err
    assert "Traceback" not in err


def write_other_dataset(path: Path) -> Path:
    """The smoke data's scenario with dt 0.1 s and 9 predicted steps."""
    import h5py

    write_braking_dataset(path, counts=(2, 2, 2), steps=14)
    with h5py.File(path, "r+") as file:
        file.attrs["dt"] = 0.1
    return path


def renamed_copy(source: Path, path: Path, scenario: str) -> Path:
    """A byte copy of the dataset `source` whose scenario attribute says `scenario`."""
    import h5py

    path.write_bytes(Path(source).read_bytes())
    with h5py.File(path, "r+") as file:
        file.attrs["scenario"] = scenario
    return path


def test_evaluate_refuses_data_of_another_scenario_naming_the_flag(smoke, tmp_path, capsys):
    data = renamed_copy(smoke["data"], tmp_path / "renamed.h5", "double_merge")
    with pytest.raises(SystemExit) as exit_info:
        argv = ["--run", str(smoke["run"]), "--data", str(data), "--out", str(tmp_path / "e.json")]
        load_tool("evaluate.py").main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert not (tmp_path / "e.json").exists()
    assert err == (
        f"error: {smoke['run'] / 'best.pt'} was trained on data with scenario 'braking_test', "
        f"but {data} has scenario 'double_merge'; pass --allow-scenario-mismatch to evaluate it "
        "on this data anyway (dt, the horizons and the agent count match)\n"
    )


def test_evaluate_on_another_scenario_when_asked_names_the_mismatch(smoke, tmp_path, capsys):
    """The same scenes under another scenario name: asked for, the scores are those of the
    original file, and the output says which scenario the run was trained on."""
    from predictor.evaluation import evaluate_run

    data = renamed_copy(smoke["data"], tmp_path / "v2.h5", "braking_v2")
    out = tmp_path / "e.json"
    argv = ["--run", str(smoke["run"]), "--data", str(data), "--out", str(out), "--no-progress"]
    load_tool("evaluate.py").main([*argv, "--allow-scenario-mismatch"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "scenario mismatch: the run was trained on braking_test data and is evaluated on "
        "braking_v2 data (same dt, horizons and agent count)"
    )
    assert " test scenes of braking_v2 (trained on braking_test) in " in lines[-1]
    stored = json.loads(out.read_text())
    assert stored["scenario_mismatch"] == {
        "trained_on": "braking_test",
        "evaluated_on": "braking_v2",
    }
    original = json.loads((smoke["run"] / "eval.json").read_text())
    assert stored["main_agents"] == original["main_agents"]
    assert stored["all_agents"] == original["all_agents"]
    assert "scenario_mismatch" not in original
    evaluation = evaluate_run(smoke["run"], data, allow_scenario_mismatch=True)
    assert evaluation.scenario_mismatch == ("braking_test", "braking_v2")


@pytest.mark.parametrize("change", ["agents", "dt"])
def test_another_scenario_with_other_shapes_or_timing_stays_refused(
    smoke, tmp_path, capsys, change
):
    import h5py

    data = tmp_path / "other.h5"
    if change == "agents":  # 5 agents where the run was trained on 4
        write_braking_dataset(data, counts=(2, 2, 2), agents=5)
        expected = "with scenario 'braking_test', num_agents 4, but"
    else:
        write_other_dataset(data)
        expected = "with scenario 'braking_test', dt 0.2, num_predicted 7, but"
    with h5py.File(data, "r+") as file:
        file.attrs["scenario"] = "braking_v2"
    argv = ["--run", str(smoke["run"]), "--data", str(data), "--out", str(tmp_path / "e.json")]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("evaluate.py").main([*argv, "--allow-scenario-mismatch"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1
    assert "--allow-scenario-mismatch" not in err  # the flag would not help
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("target", ["--out", "--save-predictions"])
def test_evaluate_unwritable_output_is_one_line(smoke, tmp_path, capsys, monkeypatch, target):
    read_only = tmp_path / "ro"
    read_only.mkdir()
    refuse_writes_in(monkeypatch, read_only)
    outputs = {"--out": tmp_path / "e.json", "--save-predictions": tmp_path / "p.npz"}
    outputs[target] = read_only / ("e.json" if target == "--out" else "p.npz")
    argv = ["--baseline", "const_vel", "--data", str(smoke["data"]), "--no-progress"]
    for flag, path in outputs.items():
        argv += [flag, str(path)]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("evaluate.py").main(argv)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == f"error: cannot write {outputs[target]}: Permission denied\n"
    assert not list(read_only.iterdir())
    if target == "--save-predictions":  # the JSON is written last: nothing was written
        assert not (tmp_path / "e.json").exists()


def test_evaluation_library_matches_the_tool_and_an_independent_ade(smoke, tmp_path):
    from predictor.evaluation import evaluate_baseline, evaluate_run
    from predictor.predictions import load_predictions
    from trajectory_data.reader import read_split

    evaluation = evaluate_run(smoke["run"], smoke["data"])
    assert evaluation.to_dict() == json.loads((smoke["run"] / "eval.json").read_text())
    evaluation.save_predictions(tmp_path / "two.npz", rows=[3, 0])
    two = load_predictions(tmp_path / "two.npz")
    assert two.scene.tolist() == [3, 0] and two.predictor == "ours"
    np.testing.assert_array_equal(two.pred_mean, evaluation.predictions.pred_mean[[3, 0]])
    # constant velocity, all agents, by hand: mean error over predicted, present agent-steps
    baseline = evaluate_baseline("const_vel", smoke["data"], "test")
    xy = read_split(smoke["data"], "test").states[..., :2].astype(np.float64)  # (n, T, N, 2)
    valid = read_split(smoke["data"], "test").valid
    pred = xy[:, 4:5] + (xy[:, 4:5] - xy[:, 3:4]) * np.arange(1, 8)[None, :, None, None]
    keep = valid[:, 5:] & valid[:, 4:5] & valid[:, 3:4]
    error = np.linalg.norm(pred - xy[:, 5:], axis=-1)[keep]
    assert baseline.scores["all_agents"]["overall"]["ade"] == pytest.approx(error.mean(), rel=1e-5)
    assert set(baseline.to_dict()) == {
        "data",
        "split",
        "scenes",
        "num_observed",
        "num_predicted",
        "dt",
        "headline",
        "predictor",
        "main_agents",
        "all_agents",
        "attention_accuracy",
        "diagnostics",
        "sampling",
        "faithfulness",
    }


def with_influence(source: Path, target: Path) -> Path:
    """A copy of the braking file whose splits record influence: each scene's focal agents
    influenced by slot 2 alone (1 m), every other pair 0 (the braking scenes' other slots
    influence nobody), so the removal test removes slot 3."""
    import dataclasses

    from trajectory_data.format import INFLUENCE, write_dataset
    from trajectory_data.reader import read_dataset

    meta, splits = read_dataset(source)
    recorded = {}
    for name, data in splits.items():
        influence = np.zeros((data.n, 2, data.num_agents, data.num_agents), np.float32)
        influence[:, :, :2, 2] = 1.0
        recorded[name] = dataclasses.replace(data, influence=influence)
    meta = dataclasses.replace(meta, recorded=(*meta.recorded, INFLUENCE))
    return write_dataset(target, meta, recorded)


def test_faithfulness_block_of_a_run_and_a_baseline(smoke, tmp_path, capsys):
    from predictor.evaluation import evaluate_baseline, evaluate_run
    from predictor.faithfulness import attention_auroc, attention_total_variation
    from trajectory_data.reader import read_split

    data = with_influence(smoke["data"], tmp_path / "influence.h5")
    evaluation = evaluate_run(smoke["run"], data)
    block = evaluation.to_dict()["faithfulness"]
    p = evaluation.predictions
    assert p.focal[:, :2].all() and not p.focal[:, 2:].any()
    # the wiring: the same measures of the evaluation's own attention, valid and focal agents
    tv = attention_total_variation(p.attention, p.valid, p.focal, p.num_observed)
    assert block["attention_tv"] == tv and tv["predicted"] > 0 and tv["observed_count"] > 0
    test = read_split(data, "test")
    auroc = attention_auroc(p.attention, test.influence, p.valid, p.focal, p.num_observed)
    assert block["auroc"] == auroc["auroc"] and block["auroc_agents"] == auroc["agents"] > 0
    assert 0 <= block["auroc"] <= 1 and block["threshold_m"] == 0.01
    # the model reads its neighbours: removing slot 3 moves its predictions
    assert block["robustness_m"] > 0 and block["removed_mean"] == 1.0
    assert block["robustness_ratio"] == pytest.approx(
        block["robustness_m"] / evaluation.scores["main_agents"]["overall"]["ade"]
    )
    # constant velocity reads no neighbours: a shift of exactly 0, attention measures None
    baseline = evaluate_baseline("const_vel", data, "test").to_dict()["faithfulness"]
    assert baseline["robustness_m"] == 0.0 and baseline["robustness_pairs"] > 0
    assert baseline["auroc"] is None and baseline["attention_tv"]["predicted"] is None
    # without influence only the total variation is measured
    plain = evaluate_run(smoke["run"], smoke["data"]).to_dict()["faithfulness"]
    assert set(plain) == {"attention_tv"} and plain["attention_tv"] == tv
    # the tool prints one line with the parts that exist
    out = tmp_path / "e.json"
    argv = ["--run", str(smoke["run"]), "--data", str(data), "--out", str(out), "--no-progress"]
    load_tool("evaluate.py").main(argv)
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("faithfulness"))
    assert f"attention AUROC {block['auroc']:.3f} against influence > 0.01 m" in line
    assert f"removed {block['robustness_m']:.3f} m" in line and "attention TV per step" in line
    tool = load_tool("evaluate.py")
    assert tool.format_faithfulness(baseline) == (
        f"faithfulness: shift when agents without influence are removed 0.000 m, 0.00 x ADE "
        f"({baseline['robustness_pairs']} pairs)"
    )
    assert tool.format_faithfulness({"attention_tv": {"observed": None, "predicted": None}}) == ""


def test_the_table_keeps_its_columns_apart_whatever_the_nll():
    """A ridge fit's NLL can reach 1e7 nats: every cell of every row stays a separate field."""
    evaluate_tool = load_tool("evaluate.py")
    group = {"ade": 1.0, "fde": 2.0, "scenes": 3, "min_ade": 0.5, "min_fde": 1.0, "k": 20}
    rows = {"a": {**group, "miss_rate": 0.485, "nll": 22151240.55}}
    rows["overall"] = {**group, "miss_rate": 0.5, "nll": 4.866}
    result = {
        key: {"overall": rows["overall"], "cases": {"a": rows["a"]}}
        for key in ("main_agents", "all_agents")
    }
    result["attention_accuracy"] = {
        "overall": {"accuracy": None},
        "cases": {"a": {"accuracy": 0.9}},
    }
    header, _, case_row, overall_row = evaluate_tool.format_table(result, ("a",)).splitlines()
    assert len(case_row.split()) == len(overall_row.split()) == 11
    assert case_row.split()[7:9] == ["0.485", "2.215e+07"]
    assert overall_row.split()[7:9] == ["0.500", "4.866"]
    assert len(case_row) == len(overall_row) == len(header)
