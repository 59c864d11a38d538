"""tools/train.py: a subprocess smoke run (conftest's `smoke`), checkpoints old and new, the
neighbour graph kept, the device, and failures that leave one line and nothing half-written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import TINY, load_tool, refuse_writes_in, run_tool


def test_train_smoke_run_writes_the_run_files(smoke):
    trained = smoke["trained"]
    assert trained.returncode == 0, trained.stderr
    assert trained.stdout.strip().count("\n") == 0 and "trained ours for 2 epochs" in trained.stdout
    assert "train ours" in trained.stderr  # the tqdm bar
    run = smoke["run"]
    assert {p.name for p in run.iterdir()} >= {"config.json", "metrics.jsonl", "best.pt", "last.pt"}
    lines = (run / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [1, 2]


def test_checkpoint_missing_a_config_field_is_rejected(smoke, tmp_path: Path):
    import torch

    from predictor.checkpoints import CheckpointError, load_model

    checkpoint = torch.load(smoke["run"] / "best.pt", weights_only=True)
    load_model(smoke["run"] / "best.pt")  # the intact file loads
    del checkpoint["model_config"]["mean_prior"]  # as written by an older model version
    old = tmp_path / "old.pt"
    torch.save(checkpoint, old)
    with pytest.raises(CheckpointError, match="lacks field"):
        load_model(old)


def test_checkpoint_of_an_older_version_loads_with_the_behaviour_it_was_trained_with(
    smoke, tmp_path: Path
):
    import torch

    from predictor.checkpoints import load_model
    from predictor.run_state import resume_configs
    from predictor.stored_config import ADDED_MODEL_FIELDS, ADDED_TRAIN_FIELDS

    checkpoint = torch.load(smoke["run"] / "best.pt", weights_only=True)
    model, _ = load_model(smoke["run"] / "best.pt")
    assert {"neighbours", "highway_attended"} <= set(ADDED_MODEL_FIELDS)
    assert "bucket_batches" in ADDED_TRAIN_FIELDS
    for name in ("neighbours", "neighbour_k", "highway_attended", "attention_gain"):
        del checkpoint["model_config"][name]  # as written before these fields existed
    for name in ("bucket_batches", "compile_graph_step", "device"):
        del checkpoint["train_config"][name]
    old = tmp_path / "old"
    shutil.copytree(smoke["run"], old)
    torch.save(checkpoint, old / "best.pt")
    torch.save(checkpoint, old / "last.pt")
    restored, _ = load_model(old / "best.pt")
    assert restored.config == model.config  # the smoke run used the paper's values
    for name, value in model.state_dict().items():
        torch.testing.assert_close(restored.state_dict()[name], value)
    _, train_config = resume_configs(old, {"epochs": 3})
    assert train_config.bucket_batches is False and train_config.epochs == 3
    assert train_config.device == "cpu"  # a field added at its default: nothing listed for it


def test_checkpoint_that_used_a_removed_option_is_refused_in_one_line(smoke, tmp_path: Path):
    """A run written while the rejected options existed loads where it left them at the value
    the current code computes, and is refused, naming the option and the commit, where not."""
    import torch

    from predictor.stored_config import REMOVED_IN, REMOVED_MODEL_FIELDS, REMOVED_TRAIN_FIELDS

    checkpoint = torch.load(smoke["run"] / "best.pt", weights_only=True)
    checkpoint["model_config"].update(REMOVED_MODEL_FIELDS)  # as written before the removal
    checkpoint["train_config"].update(REMOVED_TRAIN_FIELDS)
    for name, changes in (("neutral", {}), ("used", {"observed_jitter": 2})):
        run = tmp_path / name
        shutil.copytree(smoke["run"], run)
        stored = {**checkpoint, "train_config": {**checkpoint["train_config"], **changes}}
        if changes:
            stored["model_config"] = {**stored["model_config"], "acceleration_input": True}
        torch.save(stored, run / "best.pt")
        result = run_tool("evaluate.py", "--run", run, "--data", smoke["data"], "--overwrite")
        if not changes:
            assert result.returncode == 0, result.stderr
            continue
        assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
        assert "acceleration_input=True" in result.stderr and REMOVED_IN in result.stderr


def test_train_keeps_the_neighbour_graph_in_the_checkpoint(smoke, tmp_path: Path, capsys):
    import torch

    from predictor.checkpoints import load_model

    run = tmp_path / "radius"
    args = ["--data", smoke["data"], "--out", run, "--epochs", "1", "--no-progress", *TINY]
    graph = ["--set", "model.neighbours=radius", "--set", "model.neighbour_radius_m=15"]
    graph += ["--set", "train.bucket_batches=no"]
    load_tool("train.py").main([str(a) for a in [*args, *graph]])
    assert "trained ours for 1 epochs" in capsys.readouterr().out
    stored = torch.load(run / "best.pt", weights_only=True)
    assert stored["model_config"]["neighbours"] == "radius"
    assert stored["model_config"]["neighbour_radius_m"] == 15.0
    assert stored["train_config"]["bucket_batches"] is False
    model, _ = load_model(run / "best.pt")
    assert (model.config.neighbours, model.config.neighbour_radius_m) == ("radius", 15.0)


def test_train_unwritable_run_directory_is_one_line(smoke, tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    refuse_writes_in(monkeypatch, run)
    argv = ["--data", str(smoke["data"]), "--out", str(run), "--epochs", "1", "--no-progress"]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("train.py").main([*argv, *TINY])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err == f"error: cannot write {run / 'config.json'}: Permission denied\n"
    assert not run.exists()


def test_train_interrupted_in_the_first_epoch_keeps_nothing(smoke, tmp_path, capsys, monkeypatch):
    import predictor.training

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(predictor.training, "train_step", interrupt)
    run = tmp_path / "run"
    argv = ["--data", str(smoke["data"]), "--out", str(run), "--no-progress", *TINY]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("train.py").main(argv)
    assert exit_info.value.code == 130
    err = capsys.readouterr().err
    assert err == (
        f"error: interrupted before the first epoch ended; nothing was kept in {run}; run the "
        "same command again to start over\n"
    )
    assert not run.exists()


def test_a_cuda_device_where_torch_finds_none_is_one_line_and_writes_nothing(smoke, tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA device")
    run = tmp_path / "gpu"
    result = run_tool("train.py", "--data", smoke["data"], "--out", run, "--device", "cuda")
    assert result.returncode == 2 and not run.exists()
    assert result.stderr == "error: train.device is 'cuda', but torch finds no CUDA device here\n"
    bad = run_tool("train.py", "--data", smoke["data"], "--out", run, "--device", "gpu")
    assert bad.returncode == 2 and "train.device must be 'cpu', 'cuda' or 'cuda:N'" in bad.stderr


def test_an_explicit_cpu_device_trains_what_the_default_trains(smoke, tmp_path):
    import torch

    common = ["--data", smoke["data"], "--epochs", "1", "--preset", "paper", *TINY]
    for name, extra in (("default", []), ("cpu", ["--device", "cpu"])):
        assert run_tool("train.py", *common, "--out", tmp_path / name, *extra).returncode == 0
    weights = [
        torch.load(tmp_path / name / "last.pt", weights_only=True)["model_state"]
        for name in ("default", "cpu")
    ]
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
