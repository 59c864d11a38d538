"""One exit-status rule for every tool (docs/CLI.md): 2 usage or input error, 1 failed work, 130
interrupted; each error is one line on stderr, never a traceback."""

from __future__ import annotations

import errno
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO_ROOT, load_tool, run_tool, tool_env, write_predictions_npz
from test_training import write_braking_dataset

TOOLS = (
    "demo.py",
    "evaluate.py",
    "generate.py",
    "import_data.py",
    "inspect_data.py",
    "list_scenarios.py",
    "play.py",
    "plot.py",
    "reproduce.py",
    "train.py",
    "view.py",
)
TINY = [
    *("--set", "model.embed_dim=8", "--set", "model.edge_hidden=8"),
    *("--set", "model.node_hidden=12", "--set", "model.attn_dim=4"),
]


def test_every_tool_is_covered():
    assert sorted(p.name for p in (REPO_ROOT / "tools").glob("*.py")) == sorted(TOOLS)


@pytest.mark.parametrize("tool", TOOLS)
def test_a_usage_error_is_exit_2_and_one_line(tool):
    done = run_tool(tool, "--no-such-option", timeout=120)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tool}: "), done.stderr
    assert lines[0].endswith(" (see --help)") and done.stdout == ""


# ---- interrupts ------------------------------------------------------------------------------
MARKER = "TEST-BLOCKED-HERE"
# Runs a tool as `python tools/X.py ARGS` would, after replacing one library function it calls
# during its work by one that says so on stderr and sleeps: the Ctrl-C then comes, for sure,
# while the tool is at work, however fast or slow the machine.
BLOCKING_RUNNER = f"""
import importlib, runpy, sys, time
module, name, tool = sys.argv[1:4]
def blocked(*args, **kwargs):
    print("{MARKER}", file=sys.stderr, flush=True)
    time.sleep(600)
setattr(importlib.import_module(module), name, blocked)
sys.argv = [tool, *sys.argv[4:]]
runpy.run_path(tool, run_name="__main__")
"""


def start(argv: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=tool_env(),
        cwd=REPO_ROOT,
        start_new_session=True,  # its own process group, as a job in a terminal
    )


def wait_for(process: subprocess.Popen, stream, text: str, timeout: float = 300.0) -> bytes:
    """Read `stream` of `process` until `text` appeared; returns what was read."""
    seen, deadline = b"", time.monotonic() + timeout
    while text.encode() not in seen:
        ready, _, _ = select.select([stream], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(stream.fileno(), 65536) if ready else b""
        if not chunk:  # timed out, or the tool ended
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            pytest.fail(f"{text!r} did not appear within {timeout} s: {seen[-2000:]!r}")
        seen += chunk
    return seen


def interrupt(process: subprocess.Popen) -> tuple[bytes, bytes]:
    """Ctrl-C as a terminal sends it (to the process group); (stdout, stderr) to the end."""
    try:
        os.killpg(process.pid, signal.SIGINT)
        return process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()


def error_lines(stderr: bytes) -> list[str]:
    """The lines on stderr after the test's marker (and progress bars' carriage returns)."""
    text = stderr.decode().split(MARKER)[-1]
    return [line for line in text.replace("\r", "\n").splitlines() if line.strip()]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("inputs")
    return {
        "data": write_braking_dataset(root / "braking.h5"),
        "pred": write_predictions_npz(root / "pred.npz"),
        "root": root,
    }


@pytest.mark.parametrize(
    ("tool", "target", "args", "message"),
    [
        (
            "evaluate.py",
            "predictor.evaluation.evaluate_baseline",
            ["--baseline", "const_vel", "--data", "{data}", "--out", "{tmp}/e.json"],
            "error: interrupted; nothing was written",
        ),
        (
            "plot.py",
            "predictor.plots.plot_predictions",
            ["predictions", "{pred}", "--out", "{tmp}/p.png"],
            "error: interrupted",
        ),
        (
            "inspect_data.py",
            "trajectory_data.reader.summarize",
            ["{data}"],
            "error: interrupted",
        ),
        (
            "import_data.py",
            "trajectory_data.importers.interaction.import_interaction",
            ["interaction", "{data}", "--out", "{tmp}/i.h5"],
            "error: interrupted; nothing was written",
        ),
        (
            "play.py",
            "scenarios.env_module",
            ["--scenario", "halting_car", "--record", "{tmp}/e.gif"],
            "error: interrupted; nothing was written",
        ),
        (
            "view.py",
            "pipeline.viewer.make_viewer",
            ["{data}", "--predictions", "{pred}", "--out", "{tmp}/v.html"],
            "error: interrupted",
        ),
        (
            "train.py",
            "predictor.training.build_state",
            ["--data", "{data}", "--out", "{tmp}/run"],
            "error: interrupted before training started; nothing in {tmp}/run changed",
        ),
    ],
)
def test_ctrl_c_at_work_is_exit_130_and_one_line(inputs, tmp_path, tool, target, args, message):
    names = {**inputs, "tmp": tmp_path}
    argv = [a.format(**names) for a in args]
    module, name = target.rsplit(".", 1)
    process = start(["-c", BLOCKING_RUNNER, module, name, f"tools/{tool}", *argv])
    wait_for(process, process.stderr, MARKER)
    out, err = interrupt(process)
    assert process.returncode == 130, err.decode()[-2000:]
    assert error_lines(err) == [message.format(**names)]
    assert "Traceback" not in err.decode() and out == b""
    assert [p.name for p in tmp_path.iterdir()] == []  # nothing written


def test_ctrl_c_during_a_real_training_is_130_and_says_what_is_kept(inputs, tmp_path):
    run = tmp_path / "run"
    argv = ["--data", str(inputs["data"]), "--out", str(run), "--epochs", "100000", *TINY]
    process = start(["tools/train.py", *argv])
    wait_for(process, process.stderr, "step/s")  # the bar has moved: training is at work
    out, err = interrupt(process)
    assert process.returncode == 130, err.decode()[-2000:]
    last = err.decode().replace("\r", "\n").splitlines()[-1]
    assert "Traceback" not in err.decode() and out == b""
    if (run / "last.pt").exists():  # an epoch had ended: the message hands on the run
        assert last.startswith(f"error: interrupted; {run} holds the run after epoch ")
        assert last.endswith(" --resume")
    else:
        assert last == (
            f"error: interrupted before the first epoch ended; nothing was kept in {run}; run "
            "the same command again to start over"
        )
        assert not run.exists()


def test_ctrl_c_during_the_demo_is_130_and_says_what_is_kept(tmp_path):
    out_dir = tmp_path / "demo"
    process = start(["tools/demo.py", "--out", str(out_dir), "--epochs", "1000"])
    wait_for(process, process.stdout, "== train")
    out, err = interrupt(process)
    assert process.returncode == 130, err.decode()[-2000:]
    lines = err.decode().replace("\r", "\n").splitlines()
    assert lines[-1] == (
        f"error: interrupted; {out_dir} holds what was done so far; run the demo again to start "
        "over"
    )
    assert "Traceback" not in err.decode()


# ---- failed work -----------------------------------------------------------------------------
def test_a_diverged_training_is_exit_1(inputs, tmp_path):
    run = tmp_path / "run"
    argv = [
        "--data",
        inputs["data"],
        "--out",
        run,
        "--set",
        "train.lr=1e30",
        "--epochs",
        "3",
        *TINY,
    ]
    done = run_tool("train.py", *argv, "--no-progress")
    assert done.returncode == 1, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: training diverged: non-finite loss")


def _disk_full(monkeypatch) -> None:
    """Every rename of a finished temporary file into place fails: no space left."""

    def replace(src, dst) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))

    monkeypatch.setattr(os, "replace", replace)


@pytest.mark.parametrize(
    ("tool", "args", "written"),
    [
        ("evaluate.py", ["--baseline", "const_vel", "--data", "{data}", "--out", "{out}"], "{out}"),
        ("plot.py", ["predictions", "{pred}", "--out", "{out}"], "{out}"),
        ("view.py", ["{data}", "--out", "{out}"], "{out}"),
        ("train.py", ["--data", "{data}", "--out", "{out}", "--epochs", "1", *TINY], None),
        (
            "generate.py",
            ["--scenario", "halting_car_v0", "--num-major", "2", "--out", "{out}"],
            None,
        ),
    ],
)
def test_a_full_disk_is_failed_work_exit_1(
    inputs, tmp_path, capsys, monkeypatch, tool, args, written
):
    out = tmp_path / {"plot.py": "out.png", "view.py": "out.html"}.get(tool, "out")
    argv = [a.format(**inputs, out=out) for a in [*args, "--no-progress"]]
    if tool == "plot.py":
        argv.remove("--no-progress")
    module = load_tool(tool)
    _disk_full(monkeypatch)
    with pytest.raises(SystemExit) as done:
        module.main(argv)
    assert done.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: cannot write ")
    assert err.endswith(": No space left on device\n")
    assert not out.exists()


def test_a_reproduction_with_failed_runs_is_exit_1_naming_the_first(tmp_path, capsys, monkeypatch):
    from pipeline.reproduction import Outcome, RunCounts

    reproduce = load_tool("reproduce.py")
    counts = RunCounts(
        datasets_generated=0,
        datasets_reused=1,
        runs=3,
        reused=0,
        trained=2,
        resumed=0,
        failed=1,
        failures=("runs/x: non-finite loss",),
        skipped=0,
        reused_from_store=0,
        kept=2,
    )
    report = tmp_path / "RESULTS.md"
    monkeypatch.setattr(reproduce, "reproduce", lambda *a, **k: Outcome(report, 0, counts, 1.0))
    argv = ["--settings", "hc_go", "--out-dir", str(tmp_path / "cache"), "--report", str(report)]
    with pytest.raises(SystemExit) as done:
        reproduce.main([*argv, "--no-store"])
    assert done.value.code == 1
    captured = capsys.readouterr()
    assert captured.out.startswith(f"wrote {report}")
    assert captured.err == "error: 1 of 3 runs failed (first: runs/x: non-finite loss)\n"
