"""pipeline.api: the three calls do what the tools do (the same dataset bytes as
tools/generate.py, the same stored configuration as tools/train.py --show-config, the same
scores as predictor.evaluation), fail with one-line errors, and say in help() what they raise."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import pytest
from conftest import run_tool

from pipeline import api
from predictor.evaluation import evaluate_baseline, evaluate_run

SMALL = {"num_major": 4, "minor_ratio": 0.5, "num_test": 2, "seed": 3}
TINY = {"model.embed_dim": 8, "model.edge_hidden": 8, "model.node_hidden": 12, "model.attn_dim": 4}


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("api")
    data = api.generate("double_merge_v1", root / "dm.h5", progress=False, **SMALL)
    run = api.train(
        data, root / "run", epochs=1, seed=2, settings={**TINY, "train.lr": 0.002}, progress=False
    )
    return {"root": root, "data": data, "run": run}


def test_generate_writes_the_bytes_the_tool_writes(trained, tmp_path):
    by_tool = tmp_path / "tool.h5"
    args = ["--scenario", "double_merge_v1", "--num-major", "4", "--minor-ratio", "0.5"]
    args += ["--num-test", "2", "--seed", "3", "--out", by_tool, "--no-progress"]
    assert run_tool("generate.py", *args).returncode == 0
    assert by_tool.read_bytes() == trained["data"].read_bytes()


def test_train_stores_the_configuration_the_tool_shows(trained):
    shown = run_tool(
        "train.py",
        "--show-config",
        "--epochs",
        "1",
        "--seed",
        "2",
        *(part for key, value in TINY.items() for part in ("--set", f"{key}={value}")),
        "--set",
        "train.lr=0.002",
    )
    assert shown.returncode == 0, shown.stderr
    stored = json.loads((trained["run"] / "config.json").read_text())
    expected = json.loads(shown.stdout)
    expected["model"]["num_roles"] = 3  # resolved from the data's role names when training
    assert {k: stored[k] for k in ("model", "train", "preset")} == expected
    assert stored["preset"] == "agent" and stored["train"]["lr"] == 0.002


def test_evaluate_scores_as_the_evaluation_layer(trained):
    data, run = trained["data"], trained["run"]
    assert api.evaluate(data, run=run).scores == evaluate_run(run, data).scores
    assert (
        api.evaluate(data, baseline="const_vel").scores
        == evaluate_baseline("const_vel", data).scores
    )


def test_resume_continues_the_run_and_refuses_another_configuration(trained, tmp_path):
    from predictor.run_state import ResumeMismatch, run_status

    run = tmp_path / "run"
    api.train(trained["data"], run, epochs=1, seed=2, settings=TINY, progress=False)
    api.train(trained["data"], run, epochs=2, resume=True, progress=False)
    assert run_status(run).epoch == 2 and run_status(run).finished
    with pytest.raises(ResumeMismatch, match="lr"):
        api.train(trained["data"], run, epochs=3, resume=True, settings={"train.lr": 0.5})


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda d, o: api.generate("double_merge_v9", o / "x.h5"), "double_merge_v9"),
        (lambda d, o: api.train(d, o / "r", settings={"model.fram": "agent"}), "model.frame"),
        (lambda d, o: api.train(d, o / "r", settings={"train.lr": -1}), "train.lr must be > 0"),
        (lambda d, o: api.train(d, o / "r", preset="nope"), "unknown preset"),
        (lambda d, o: api.evaluate(d), "give one of run and baseline"),
    ],
)
def test_bad_arguments_raise_one_line_value_errors(trained, tmp_path, call, message):
    with pytest.raises(ValueError, match=message) as err:
        call(trained["data"], tmp_path)
    assert "\n" not in str(err.value)
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize("name", ["generate", "train", "evaluate"])
def test_help_says_what_each_call_raises(name):
    doc = inspect.getdoc(getattr(api, name))
    assert "Raises ValueError" in doc
