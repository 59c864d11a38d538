"""tools/generate.py from the command line: summary, refusals, bad input in one line, and
stopping it by a signal (nothing half-written)."""

from __future__ import annotations

import errno
import importlib.util
import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import load_tool, run_tool, tool_env

from pipeline import generation
from scenarios import FAMILIES
from trajectory_data.reader import read_meta

REPO = Path(__file__).resolve().parents[1]
TOOL = REPO / "tools" / "generate.py"
generate_tool = load_tool("generate.py")


def run_generate(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return run_tool("generate.py", *args, timeout=timeout)


# ---- the command-line tool ---------------------------------------------------------------------
def test_cli_smoke_summary_and_refuses_overwrite(tmp_path):
    out = tmp_path / "dm.h5"
    args = [
        "--scenario",
        "double_merge_v0",
        "--num-major",
        "3",
        "--minor-ratio",
        "0.8",
        "--num-test",
        "2",
        "--out",
        str(out),
    ]
    result = run_generate(*args)
    assert result.returncode == 0, result.stderr
    assert re.fullmatch(
        rf"wrote {re.escape(str(out))}: train 2 major \+ 2 minor; val 1 major \+ 0 minor; "
        r"test 2 major \+ 2 minor \(22 agents, 60 steps of 0.2 s; 0 unsafe episodes replaced\) "
        r"in \d+\.\d s\n",
        result.stdout,
    ), result.stdout
    assert read_meta(out).num_steps > 0
    # no silent phase: after the progress bar, a status line while the file is written
    assert f"writing 9 trajectories to {out} ...\n" in result.stderr
    first = out.read_bytes()
    again = run_generate(*args)
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert out.read_bytes() == first
    replaced = run_generate(*args, "--overwrite", "--seed", "3")
    assert replaced.returncode == 0 and out.read_bytes() != first


def test_a_family_name_means_the_latest_version_and_says_so(tmp_path):
    out = tmp_path / "hc.h5"
    args = ["--scenario", "halting_car", "--num-major", "2", "--num-test", "1", "--out", str(out)]
    result = run_generate(*args, "--minor-ratio", "0.5")
    assert result.returncode == 0, result.stderr
    latest = FAMILIES["halting_car"][-1].name
    notice = [line for line in result.stderr.splitlines() if line.startswith("notice:")]
    assert notice == [
        f"notice: using the latest version {latest} for the unversioned name "
        "'halting_car' (name a version, e.g. halting_car_v0, to pin one)"
    ]
    meta = read_meta(out)
    assert meta.scenario == latest and meta.config["generator"]["scenario"] == meta.scenario
    for old_spelling in ("halting_car_v0", "double_merge_v0"):
        pinned = run_generate("--scenario", old_spelling, *args[2:], "--overwrite")
        assert pinned.returncode == 0 and "notice" not in pinned.stderr
        assert read_meta(out).scenario == old_spelling


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["--scenario", "hovercraft"],
            "unknown scenario 'hovercraft'; choose from double_merge_v0",
        ),
        (["--scenario", "halting_car_v0", "--minor-ratio", "-0.1"], "--minor-ratio"),
        (
            ["--scenario", "halting_car_v0", "--minor-ratio", "1.5"],
            "--minor-ratio must be in [0, 1] (the minor case is the rarer one; for more of the "
            "other case, make it the --major-case), got 1.5",
        ),
        (
            ["--scenario", "halting_car_v0", "--num-major", "4", "--num-minor", "6"],
            "--num-minor (6) must be at most --num-major (4)",
        ),
        (["--scenario", "halting_car_v0", "--minor-ratio", "1e6"], "--minor-ratio"),
        (["--scenario", "halting_car_v0", "--num-major", "2.5"], "invalid int"),
        (["--scenario", "halting_car_v0", "--num-test", "ten"], "invalid int"),
        (["--scenario", "halting_car_v0", "--num-major", "0"], "--num-major must be at least 1"),
        (["--scenario", "halting_car_v0", "--num-test", "-1"], "--num-test must be at least 0"),
        (["--scenario", "halting_car_v0", "--val-fraction", "1.0"], "--val-fraction"),
        (["--scenario", "halting_car_v0", "--val-fraction", "-0.2"], "--val-fraction"),
        (["--scenario", "halting_car_v0", "--major-case", "major"], "--major-case"),
        (["--scenario", "halting_car_v0", "--seed", "-1"], "seed must be at least 0"),
        (["--scenario", "halting_car_v0", "--workers", "0"], "--workers"),
        (
            ["--scenario", "halting_car_v0", "--batch-scenes", "0"],
            "--batch-scenes must be at least 1",
        ),
        (["--scenario", "halting_car_v0", "--minor-ratio", "0.3", "--num-minor", "3"], "either"),
        (
            ["--scenario", "halting_car_v0", "--address", "head:6379"],
            "--address needs --backend ray",
        ),
        (["--scenario", "halting_car_v0", "--seed", str(2**62)], "seed must be at most"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_file(tmp_path, argv, message):
    out = tmp_path / "x.h5"
    result = run_generate(*argv, "--out", str(out))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in result.stderr
    assert lines[0].startswith("error: ")
    assert list(tmp_path.iterdir()) == []


def test_output_below_a_file_exits_2(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    result = run_generate(
        "--scenario",
        "halting_car_v0",
        "--num-major",
        "2",
        "--num-test",
        "1",
        "--out",
        str(blocker / "sub" / "x.h5"),
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines() == [
        f"error: cannot write {blocker / 'sub' / 'x.h5'}: Not a directory: {blocker / 'sub'}"
    ]


def test_unwritable_directory_exits_2(tmp_path, monkeypatch, capsys):
    # root ignores permission bits, so the refusal of a read-only directory is simulated where
    # the file is created: the real write_dataset raises what h5py/os raise there.
    def refuse(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr(generation, "write_dataset", refuse)
    out = tmp_path / "x.h5"
    with pytest.raises(SystemExit) as exit_:
        generate_tool.main(
            ["--scenario", "halting_car_v0", "--num-major", "1", "--num-test", "0"]
            + ["--out", str(out)]
        )
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == f"error: cannot write {out}: Permission denied"
    assert list(tmp_path.iterdir()) == []


# ---- interrupting the tool ---------------------------------------------------------------------
PROGRESS = re.compile(rb"\| *[1-9]\d*/\d+ \[")  # tqdm: at least one trajectory done


def start_and_wait_for_progress(
    out: Path, workers: int, timeout: float = 600, extra: tuple[str, ...] = ()
):
    """Start a long generation; return (process, stderr so far) once a trajectory is done."""
    process = subprocess.Popen(
        [sys.executable, str(TOOL), "--scenario", "double_merge_v0", "--num-major", "5000"]
        + ["--workers", str(workers), "--out", str(out), *extra],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group, like a job in a terminal
        env=tool_env(),
    )
    seen = b""
    deadline = time.monotonic() + timeout
    while not PROGRESS.search(seen):
        ready, _, _ = select.select([process.stderr], [], [], max(0.0, deadline - time.monotonic()))
        chunk = os.read(process.stderr.fileno(), 65536) if ready else b""
        if not chunk:  # timed out, or the tool ended
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
            pytest.fail(f"no progress within {timeout} s; stderr: {seen[-1000:]!r}")
        seen += chunk
    return process, seen


def group_ends(group: int, within: float) -> bool:
    """Whether process group `group` has no process left within `within` seconds."""
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


RAY = pytest.param(
    (2, ("--backend", "ray")),
    id="ray",
    marks=pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray not installed"),
)


SHARDS = (2, ("--shard-size", "10"))  # a pool per shard of 10, the temporary folder removed


@pytest.mark.parametrize(
    "run", [(1, ()), (2, ()), SHARDS, RAY], ids=["workers1", "workers2", "shards", "ray"]
)
@pytest.mark.parametrize(
    "sig, to_group",
    [(signal.SIGINT, True), (signal.SIGTERM, False)],
    ids=["ctrl-c-to-the-group", "sigterm-to-the-tool"],
)
def test_interrupted_run_leaves_no_file(tmp_path, sig, to_group, run):
    workers, extra = run
    out = tmp_path / ("big" if "--shard-size" in extra else "big.h5")
    process, seen = start_and_wait_for_progress(out, workers, extra=extra)
    try:
        if to_group:  # what a terminal's Ctrl-C does: the tool and its workers get SIGINT
            os.killpg(process.pid, sig)
        else:
            process.send_signal(sig)
        stdout, rest = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    stderr = (seen + rest).decode()
    assert process.returncode == 130, stderr[-2000:]
    assert "Traceback" not in stderr and "cffi" not in stderr and "Exception" not in stderr
    lines = [line for line in re.split(r"[\r\n]", stderr) if line.strip()]
    assert lines[-1] == "error: interrupted; nothing was written"
    assert sum("error" in line for line in lines) == 1
    assert stdout == b""
    assert list(tmp_path.iterdir()) == []
    # no worker (nor Ray process) outlives the tool; generous for Ray's shutdown on a busy machine
    assert group_ends(process.pid, within=120.0)
