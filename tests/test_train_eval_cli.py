"""tools/train.py and tools/evaluate.py: a subprocess smoke run and one-line usage errors."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, tool_env
from test_training import write_braking_dataset

TINY = ["--embed-dim", "8", "--edge-hidden", "8", "--node-hidden", "12", "--attn-dim", "4"]
NPZ_KEYS = {
    "pred_mean",
    "true_xy",
    "valid",
    "case",
    "case_names",
    "role_names",
    "roles",
    "attention",
    "attention_label",
    "interaction",
    "num_observed",
    "dt",
}


def run_tool(name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / name), *map(str, args)],
        capture_output=True,
        text=True,
        env=tool_env(),
        timeout=120,
    )


def load_tool(name: str):
    """Import tools/<name>.py as a module (for fast in-process error checks)."""
    sys.path.insert(0, str(REPO_ROOT / "tools"))
    spec = importlib.util.spec_from_file_location(f"tool_{name}", REPO_ROOT / "tools" / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> dict:
    """Train 2 epochs and evaluate once, in subprocesses."""
    root = tmp_path_factory.mktemp("smoke")
    data = write_braking_dataset(root / "braking.h5", counts=(6, 3, 4))
    run = root / "run"
    trained = run_tool(
        "train.py",
        "--data",
        data,
        "--out",
        run,
        "--epochs",
        "2",
        "--seed",
        "0",
        "--batch-size",
        "4",
        *TINY,
    )
    evaluated = run_tool(
        "evaluate.py", "--run", run, "--data", data, "--save-predictions", root / "pred.npz"
    )
    return {"root": root, "data": data, "run": run, "trained": trained, "evaluated": evaluated}


def test_train_smoke_run_writes_the_run_files(smoke):
    trained = smoke["trained"]
    assert trained.returncode == 0, trained.stderr
    assert trained.stdout.strip().count("\n") == 0 and "trained ours for 2 epochs" in trained.stdout
    assert "train ours" in trained.stderr  # the tqdm bar
    run = smoke["run"]
    assert {p.name for p in run.iterdir()} >= {"config.json", "metrics.jsonl", "best.pt", "last.pt"}
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2]


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
        ("train.py", ["--data", "{foreign}", "--out", "{tmp}/r"], "not an HDF5 file"),
        ("train.py", ["--data", "{data}", "--out", "{run}"], "not empty"),
        ("train.py", ["--data", "{data}", "--out", "{tmp}/r", "--resume"], "no such checkpoint"),
        ("evaluate.py", ["--run", "{run}", "--data", "{missing}"], "does not exist"),
        (
            "evaluate.py",
            ["--run", "{run}", "--data", "{foreign}", "--out", "{tmp}/e.json"],
            "not an HDF5 file",
        ),
        ("evaluate.py", ["--run", "{run}", "--data", "{data}"], "already exists"),
        (
            "evaluate.py",
            ["--run", "{tmp}", "--data", "{data}", "--out", "{tmp}/e.json"],
            "checkpoint",
        ),
        ("evaluate.py", ["--baseline", "magic", "--data", "{data}"], "invalid choice"),
        ("evaluate.py", ["--run", "{foreign}", "--data", "{data}"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(smoke, tmp_path, capsys, tool, args, message):
    foreign = tmp_path / "foreign.h5"
    foreign.write_text("not a dataset")
    names = {
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


def test_checkpoint_missing_a_config_field_is_rejected(smoke, tmp_path: Path):
    import torch

    from predictor.evaluation import CheckpointError, load_model

    checkpoint = torch.load(smoke["run"] / "best.pt", weights_only=True)
    load_model(smoke["run"] / "best.pt")  # the intact file loads
    del checkpoint["model_config"]["mean_prior"]  # as written by an older model version
    old = tmp_path / "old.pt"
    torch.save(checkpoint, old)
    with pytest.raises(CheckpointError, match="lacks field"):
        load_model(old)
