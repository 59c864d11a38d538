"""pipeline.pool under Ctrl-C: a stream of SIGINTs while the parent waits on its jobs ends in one
KeyboardInterrupt raised only after every job stopped at its safe point (the parent takes signals
between polls, never inside concurrent.futures' waiting code or the clean stop)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

from conftest import tool_env

from pipeline.pool import due_items

# A job that announces its start, runs until the pool's stop event is set, then holds its stop
# until the parent's signals are over and records that it ended cleanly.
JOB_MODULE = """
import os, time
from pathlib import Path
from pipeline.pool import Stopped, check_stop

def job(k):
    here = Path(os.environ["POOL_TEST_DIR"])
    (here / f"started-{k}").touch()
    try:
        for _ in range(6000):  # at most a minute, so a failing test leaves no endless process
            check_stop()
            time.sleep(0.01)
    except Stopped:
        while not (here / "burst-done").exists():
            time.sleep(0.01)
        (here / f"ended-{k}").touch()
        raise
"""

# The parent: once both jobs run, it sends itself 100 SIGINTs 5 ms apart (a held-down Ctrl-C or
# an impatient user), so signals arrive while it waits and while it stops the jobs; then the
# jobs may end.
PARENT = """
import multiprocessing, os, signal, sys, threading, time
from pathlib import Path
from pipeline.pool import run_parallel
from pool_test_job import job

here = Path(os.environ["POOL_TEST_DIR"])

def burst():
    while len(list(here.glob("started-*"))) < 2:
        time.sleep(0.01)
    for _ in range(100):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.005)
    (here / "burst-done").touch()

threading.Thread(target=burst, daemon=True).start()
try:
    run_parallel(job, [0, 1], 2, "jobs")
    print("not interrupted")
except KeyboardInterrupt:
    ended = sorted(p.name for p in here.glob("ended-*"))
    print("interrupted after", ended, "with", len(multiprocessing.active_children()), "alive")
"""


def test_repeated_ctrl_c_stops_every_job_cleanly_and_raises_once(tmp_path):
    (tmp_path / "pool_test_job.py").write_text(textwrap.dedent(JOB_MODULE))
    env = tool_env()
    env["PYTHONPATH"] = f"{tmp_path}:{env['PYTHONPATH']}"
    env["POOL_TEST_DIR"] = str(tmp_path)
    done = subprocess.run(
        [sys.executable, "-c", PARENT], capture_output=True, text=True, env=env, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    expected = "interrupted after ['ended-0', 'ended-1'] with 0 alive\n"
    assert done.stdout == expected, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr


def test_due_items_hands_out_at_most_count_and_nothing_after_the_deadline():
    queue = iter(enumerate("abcde"))
    assert due_items(queue, 2, None) == [(0, "a"), (1, "b")]
    assert due_items(queue, 0, None) == []
    assert due_items(queue, 5, time.monotonic() - 1.0) == []  # past: nothing taken
    assert due_items(queue, 5, time.monotonic() + 600.0) == [(2, "c"), (3, "d"), (4, "e")]
    assert due_items(queue, 5, None) == []  # exhausted
