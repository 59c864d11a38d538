"""tools/train.py --resume: the original command plus --resume continues a run bit for bit,
options the stored run fixes are checked against it, an interrupted --overwrite says that the
previous run was put back, and a finished run says it is finished."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest
import torch
from conftest import load_tool
from test_training import write_braking_dataset

import predictor.training
from predictor.run_state import ResumeMismatch, resume_configs, run_status
from predictor.training import NOTHING_KEPT, RESTORED, RESUMABLE, TrainingInterrupted

TINY = [
    *("--set", "model.embed_dim=8", "--set", "model.edge_hidden=8"),
    *("--set", "model.node_hidden=12", "--set", "model.attn_dim=4"),
]


@pytest.fixture
def data(tmp_path: Path) -> Path:
    """8 training scenes: 3 optimiser steps an epoch at batch size 3."""
    return write_braking_dataset(tmp_path / "braking.h5")


def command(data: Path, out: Path, *extra: str, epochs: int = 3) -> list[str]:
    """A new run's command line as a user types it: preset, variant, seed and sizes."""
    return [
        "--data",
        str(data),
        "--out",
        str(out),
        "--preset",
        "agent",
        "--variant",
        "ours",
        "--seed",
        "0",
        "--epochs",
        str(epochs),
        "--set",
        "train.batch_size=3",
        "--no-progress",
        *TINY,
        *extra,
    ]


def run_train(argv: list[str], capsys) -> tuple[int, str, str]:
    """tools/train.py's main in-process: (exit status, stdout, stderr)."""
    try:
        load_tool("train.py").main(argv)
        code = 0
    except SystemExit as done:
        code = done.code
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def interrupt_at_step(monkeypatch, step: int) -> None:
    """Ctrl-C at the `step`-th optimiser step (1-based) of the next training."""
    real, calls = predictor.training.train_step, []

    def train_step(*args, **kwargs):
        calls.append(1)
        if len(calls) == step:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(predictor.training, "train_step", train_step)


def files(run: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(run.iterdir())}


def weights(path: Path) -> dict:
    return torch.load(path, weights_only=True)["model_state"]


def metrics(run: Path) -> list:
    lines = (run / "metrics.jsonl").read_text().splitlines()
    return [(r["epoch"], r["train"], r["val"]) for r in map(json.loads, lines)]


def test_the_same_command_plus_resume_continues_bit_identically(
    data, tmp_path, capsys, monkeypatch
):
    full, cut = tmp_path / "full", tmp_path / "cut"
    assert run_train(command(data, full), capsys)[0] == 0
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 5)  # inside epoch 2
        code, out, err = run_train(command(data, cut), capsys)
    assert code == 130 and out == ""
    # the message names the state and the exact command that continues it
    prefix = f"error: interrupted; {cut} holds the run after epoch 1 of 3; continue it with: "
    assert err.startswith(prefix) and err.count("\n") == 1, err
    again = shlex.split(err[len(prefix) :])
    assert again[:2] == ["python", "tools/train.py"]
    assert again[2:] == [*command(data, cut), "--resume"]
    code, out, err = run_train(again[2:], capsys)
    assert code == 0, err
    assert out.startswith("trained ours for 3 epochs")
    for name in ("last.pt", "best.pt"):
        expected, got = weights(full / name), weights(cut / name)
        assert expected.keys() == got.keys()
        assert all(torch.equal(expected[k], got[k]) for k in expected), name
    assert metrics(cut) == metrics(full)
    assert run_status(cut).finished and run_status(cut).preset == "agent"


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--seed", "1", "--seed 1 differs from the stored run's --seed 0"),
        ("--preset", "paper", "--preset paper differs from the stored run's --preset agent"),
        (
            "--variant",
            "nonsmooth",
            "--variant nonsmooth differs from the stored run's --variant ours",
        ),
        (
            "--set",
            "train.batch_size=4",
            "--set train.batch_size=4 differs from the stored run's --set train.batch_size=3",
        ),
        (
            "--set",
            "model.standardise=no",
            "--set model.standardise=no differs from the stored run's --set model.standardise=yes",
        ),
    ],
)
def test_a_changed_fixed_option_is_refused_naming_both_values(
    data, tmp_path, capsys, monkeypatch, option, value, message
):
    run = tmp_path / "run"
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 5)
        assert run_train(command(data, run), capsys)[0] == 130
    before = files(run)
    argv = command(data, run, "--resume")
    if option in argv and option != "--set":
        argv[argv.index(option) + 1] = value
    else:  # a later --set of the same key overrides the earlier one
        argv += [option, value]
    code, out, err = run_train(argv, capsys)
    assert (code, out) == (2, "")
    assert err == (
        f"error: {message} (a resumed run keeps its configuration; only --epochs, train.threads, "
        "train.eval_every, --device may change)\n"
    )
    assert files(run) == before  # nothing touched


def test_equal_options_are_accepted_and_left_out_ones_keep_the_stored_values(
    data, tmp_path, capsys
):
    run = tmp_path / "run"
    assert run_train(command(data, run, epochs=1), capsys)[0] == 0
    # the original command with --resume and more epochs: every fixed option equal
    code, out, err = run_train(command(data, run, "--resume", epochs=2), capsys)
    assert code == 0, err
    assert out.startswith("trained ours for 2 epochs")
    # only the data, the folder and more epochs: the stored preset and sizes are kept
    short = ["--data", str(data), "--out", str(run), "--resume", "--epochs", "3", "--no-progress"]
    code, out, err = run_train(short, capsys)
    assert code == 0, err
    status = run_status(run)
    assert (status.epoch, status.epochs, status.finished, status.preset) == (3, 3, True, "agent")


def test_an_interrupted_overwrite_says_the_previous_run_was_put_back(
    data, tmp_path, capsys, monkeypatch
):
    run = tmp_path / "run"
    assert run_train(command(data, run, epochs=1), capsys)[0] == 0
    (run / "eval.json").write_text("{}")
    old = files(run)
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 1)  # before the new run's first checkpoint
        argv = command(data, run, "--overwrite", epochs=2)
        argv[argv.index("--seed") + 1] = "5"
        code, out, err = run_train(argv, capsys)
    assert (code, out) == (130, "")
    assert err == (
        f"error: interrupted before the new run's first epoch ended; the previous run in {run} "
        "was put back as it was and the new run was not kept; run the same command again to "
        "start the new run over\n"
    )
    assert "--resume" not in err
    assert files(run) == old  # byte for byte
    # the same command again trains the new run
    code, out, err = run_train(argv, capsys)
    assert code == 0, err
    assert torch.load(run / "last.pt", weights_only=True)["train_config"]["seed"] == 5


def test_an_overwrite_interrupted_after_its_first_epoch_continues_without_overwrite(
    data, tmp_path, capsys, monkeypatch
):
    run = tmp_path / "run"
    assert run_train(command(data, run, epochs=1), capsys)[0] == 0
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 4)  # the new run's epoch 2
        code, _, err = run_train(command(data, run, "--overwrite", epochs=2), capsys)
    assert code == 130
    again = shlex.split(err.split("continue it with: ", 1)[1])[2:]
    assert "--overwrite" not in again and again[-1] == "--resume"
    assert run_train(again, capsys)[0] == 0
    assert run_status(run).epoch == 2


def test_resume_of_a_finished_run_says_it_is_finished(data, tmp_path, capsys):
    run = tmp_path / "run"
    assert run_train(command(data, run, epochs=2), capsys)[0] == 0
    before = files(run)
    code, out, err = run_train(command(data, run, "--resume", epochs=2), capsys)
    assert (code, err) == (0, "")
    best = torch.load(run / "last.pt", weights_only=True)
    assert out == (
        f"run {run} is finished: 2 of 2 epochs trained, best val ADE (main agents) "
        f"{best['best_score']:.3f} m at epoch {best['best_epoch']}; nothing to resume (a larger "
        "--epochs trains it further)\n"
    )
    assert files(run) == before
    code, out, err = run_train(command(data, run, "--resume", epochs=1), capsys)
    assert (code, out) == (2, "")
    assert err == (
        f"error: {run} has trained 2 epochs already; epochs 1 asks for fewer (a run cannot be "
        "shortened)\n"
    )


def test_checkpoints_record_whether_the_run_finished(data, tmp_path, capsys, monkeypatch):
    run = tmp_path / "run"
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 5)
        assert run_train(command(data, run), capsys)[0] == 130
    stored = torch.load(run / "last.pt", weights_only=True)
    assert (stored["epoch"], stored["finished"], stored["preset"]) == (1, False, "agent")
    assert json.loads((run / "config.json").read_text())["preset"] == "agent"
    assert not run_status(run).finished
    assert run_train(command(data, run, "--resume"), capsys)[0] == 0
    stored = torch.load(run / "last.pt", weights_only=True)
    assert (stored["epoch"], stored["finished"]) == (3, True)


def _as_written_before_the_fields(run: Path) -> None:
    """Remove `preset` and `finished` from the run's checkpoints, as older versions wrote them."""
    for name in ("last.pt", "best.pt"):
        checkpoint = torch.load(run / name, weights_only=True)
        del checkpoint["preset"], checkpoint["finished"]
        torch.save(checkpoint, run / name)


def test_a_run_from_before_presets_and_finished_were_recorded(data, tmp_path, capsys):
    finished, cut = tmp_path / "finished", tmp_path / "cut"
    assert run_train(command(data, finished, epochs=1), capsys)[0] == 0
    assert run_train(command(data, cut, epochs=1), capsys)[0] == 0
    _as_written_before_the_fields(finished)
    _as_written_before_the_fields(cut)
    # finished when its epoch reached its configured epochs; preset not recorded
    status = run_status(finished)
    assert (status.finished, status.preset) == (True, None)
    code, out, _ = run_train(command(data, finished, "--resume", epochs=1), capsys)
    assert code == 0 and out.startswith(f"run {finished} is finished: 1 of 1 epochs")
    # an unrecorded preset is checked by what it sets: the agent run is no paper run
    argv = command(data, cut, "--resume", epochs=2)
    argv[argv.index("--preset") + 1] = "paper"
    code, _, err = run_train(argv, capsys)
    assert code == 2
    assert err.startswith(
        "error: --preset paper sets --set model.attended_fit=mean, but the stored run "
    )
    assert "(its preset not recorded) has edge_relations" in err and err.count("\n") == 1
    with pytest.raises(ResumeMismatch) as info:
        resume_configs(cut, {"epochs": 2}, preset="crowd")
    assert info.value.preset == "crowd" and info.value.stored != info.value.asked
    # the right preset is accepted, and from then on recorded
    code, out, err = run_train(command(data, cut, "--resume", epochs=2), capsys)
    assert code == 0, err
    assert torch.load(cut / "last.pt", weights_only=True)["preset"] == "agent"


def test_an_interrupt_says_what_the_directory_holds(data, tmp_path, monkeypatch):
    """The library's account of an interrupt, which the tool's messages rest on."""
    from predictor.presets import make_configs

    tiny = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
    configs = make_configs("ours", tiny, epochs=2, batch_size=3, preset="paper")  # 3 steps an epoch
    run = tmp_path / "run"
    train = predictor.training.train
    train(data, *configs, run, progress=False)
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 1)
        with pytest.raises(TrainingInterrupted) as info:
            train(data, *configs, run, overwrite=True, progress=False)
    assert (info.value.outcome, info.value.epoch, info.value.epochs) == (RESTORED, 2, 2)
    assert isinstance(info.value, KeyboardInterrupt)
    more = make_configs("ours", tiny, epochs=4, batch_size=3, preset="paper")
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 2)  # inside epoch 3
        with pytest.raises(TrainingInterrupted) as info:
            train(data, *more, run, resume=True, progress=False)
    assert (info.value.outcome, info.value.epoch, info.value.epochs) == (RESUMABLE, 2, 4)
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 5)  # a new run's epoch 2
        with pytest.raises(TrainingInterrupted) as info:
            train(data, *more, tmp_path / "new", progress=False)
    assert (info.value.outcome, info.value.epoch, info.value.epochs) == (RESUMABLE, 1, 4)
    with monkeypatch.context() as patch:
        interrupt_at_step(patch, 1)
        with pytest.raises(TrainingInterrupted) as info:
            train(data, *more, tmp_path / "none", progress=False)
    assert info.value.outcome == NOTHING_KEPT and not (tmp_path / "none").exists()
