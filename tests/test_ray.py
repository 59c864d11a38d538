"""The Ray backend (pipeline.ray_backend) on a local Ray instance with 2 CPUs: generation through
Ray writes the same bytes as the local backend, as one file or as shards; a reproduction sweep
through Ray gives the same results and cache as the local backend, resumes from that cache, and
reports a job that raises while the others finish; a task whose worker dies is retried, one
that dies twice is reported; Ctrl-C cancels a Ray sweep and its rerun resumes; a missing Ray is
one clear line. Skipped where Ray is not installed (`pip install -e '.[ray]'`; `make test`
installs it)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO_ROOT, load_tool, tool_env

from pipeline.generation import GenerateConfig, generate_dataset
from pipeline.protocol import QUICK_NUM_TEST, SETTING_BY_NAME, Protocol
from pipeline.ray_backend import (
    RayUnavailableError,
    TaskFailed,
    map_in_order,
    map_settled,
    ray_session,
)
from pipeline.reproduction import execute
from pipeline.run_plan import setting_jobs

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def session():
    """A local Ray instance of the tests' own (not a cluster named by the caller's RAY_ADDRESS,
    which cannot see the tests' temporary folders)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.delenv("RAY_ADDRESS", raising=False)
        with ray_session(num_cpus=2) as connected:
            yield connected


def test_local_workers_run_at_the_callers_priority(session):
    """Ray's default worker niceness (15) starves its tasks beside any busy process."""

    def niceness(_: int) -> int:
        return os.nice(0)

    assert map_in_order(niceness, [0, 1]) == [os.nice(0)] * 2


def test_generation_through_ray_writes_the_same_bytes(session, tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=6, num_minor=3, num_test=4)
    generate_dataset(config, tmp_path / "local.h5", progress=False, batch_scenes=1)  # one by one
    generate_dataset(config, tmp_path / "ray.h5", workers=2, progress=False, backend="ray")
    assert (tmp_path / "ray.h5").read_bytes() == (tmp_path / "local.h5").read_bytes()


def test_sharded_generation_through_ray_writes_the_same_bytes(session, tmp_path):
    config = GenerateConfig.for_scenario("halting_car_v0", num_major=6, num_minor=3, num_test=4)
    local = generate_dataset(config, tmp_path / "local", progress=False, shard_size=4)
    remote = generate_dataset(
        config, tmp_path / "ray", workers=2, progress=False, backend="ray", shard_size=4
    )
    files = sorted(p.name for p in local.path.parent.iterdir())
    assert len(files) == 1 + local.shards == 6  # index; train 4 + 1, val 1 + 1, test 4 + 4
    assert sorted(p.name for p in remote.path.parent.iterdir()) == files
    for name in files:
        assert (remote.path.parent / name).read_bytes() == (local.path.parent / name).read_bytes()


# Task functions are defined inside the tests: Ray ships those by value, while a function of this
# module would have to be imported by the workers, which do not see tests/.


def test_a_task_whose_worker_dies_is_retried(session, tmp_path):
    def die_once(marker: str) -> int:
        """Kill this worker process the first time (no exception: the process is gone)."""
        if not Path(marker).exists():
            Path(marker).write_text(str(os.getpid()))
            os._exit(1)
        return os.getpid()

    marker = tmp_path / "died"
    (pid,) = map_in_order(die_once, [str(marker)], max_retries=1)
    assert marker.exists() and pid != int(marker.read_text())  # a new worker ran it


def test_results_come_back_in_item_order(session):
    def magnitude(x: int) -> int:
        return abs(x)

    seen = []
    assert map_in_order(magnitude, [-3, 1, -2], on_result=seen.append) == [3, 1, 2]
    assert sorted(seen) == [1, 2, 3]


def test_a_worker_that_dies_is_retried_once_and_then_reported_and_the_rest_go_on(session, tmp_path):
    def task(item: tuple[str, str]) -> str:
        """'dies once' / 'dies always' kill their worker (once: only on the first attempt),
        'raises' raises; each attempt appends this worker's pid to the item's marker file."""
        how, marker = item
        with open(marker, "a") as stream:
            stream.write(f"{os.getpid()}\n")
        if how == "raises":
            raise ValueError("bad input\nsecond line")
        attempt = Path(marker).read_text().count("\n")
        if how == "dies always" or (how == "dies once" and attempt == 1):
            os._exit(1)
        return how

    hows = ["dies once", "dies always", "raises", "fine"]
    items = [(how, str(tmp_path / how.replace(" ", "_"))) for how in hows]
    results = map_settled(task, items, max_retries=1)
    attempts = [len(Path(marker).read_text().splitlines()) for _, marker in items]
    assert attempts == [2, 2, 1, 1]  # raising is not retried: the error would repeat
    assert results[0] == "dies once" and results[3] == "fine"
    assert results[1] == TaskFailed("worker died on each of 2 attempts (WorkerCrashedError)")
    assert results[2] == TaskFailed("ValueError: bad input")


def test_map_settled_starts_nothing_after_its_deadline(session):
    def magnitude(x: int) -> int:
        return abs(x)

    assert map_settled(magnitude, [-1, 2], deadline=time.monotonic() - 1.0) == [None, None]
    assert map_settled(magnitude, [-1, 2], deadline=time.monotonic() + 600.0) == [1, 2]


# ------------------------------------------------------------------ reproduction sweeps
TIMINGS = ("data", "train_seconds", "eval_seconds")  # the only eval.json fields allowed to differ


def tiny_protocol(seeds: int = 2) -> Protocol:
    """hc_go at --quick size, one epoch: two runs of ours and the constant-velocity baseline."""
    return Protocol(
        (SETTING_BY_NAME["hc_go"],), ("ours", "const_vel"), seeds, 1, QUICK_NUM_TEST, 0, True
    )


def evaluations(cache: Path) -> dict[str, dict]:
    """Every eval.json under cache/runs by relative path, timing fields left out."""
    found = {}
    for path in sorted((cache / "runs").rglob("eval.json")):
        result = json.loads(path.read_text())
        found[path.relative_to(cache).as_posix()] = {
            k: v for k, v in result.items() if k not in TIMINGS
        }
    return found


def test_sweep_through_ray_matches_local_and_resumes_from_its_cache(session, tmp_path):
    protocol = tiny_protocol()
    local = execute(protocol, tmp_path / "local", 2)
    through_ray = execute(protocol, tmp_path / "ray", 2, backend="ray")
    assert local == through_ray  # 3 runs trained, 1 dataset generated, nothing failed
    assert (through_ray.runs, through_ray.trained, through_ray.failed) == (3, 3, 0)
    assert evaluations(tmp_path / "ray") == evaluations(tmp_path / "local")  # training is exact
    assert len(evaluations(tmp_path / "ray")) == 3
    data = [next((tmp_path / d / "data").glob("*.h5")).read_bytes() for d in ("local", "ray")]
    assert data[0] == data[1]

    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "ray").rglob("*") if p.is_file()}
    again = execute(protocol, tmp_path / "ray", 2, backend="ray")
    assert (again.reused, again.trained, again.resumed, again.datasets_reused) == (3, 0, 0, 1)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # nothing rewritten


def test_a_sweep_job_that_raises_is_reported_and_the_others_finish(session, tmp_path):
    cache = tmp_path / "cache"
    protocol = tiny_protocol()
    broken = next(j for j in setting_jobs(protocol, protocol.settings[0], cache) if j.seed == 1)
    Path(broken.run_dir).mkdir(parents=True)
    (Path(broken.run_dir) / "last.pt").write_bytes(b"not a checkpoint")  # resuming raises
    counts = execute(protocol, cache, 2, backend="ray")
    assert (counts.runs, counts.trained, counts.failed) == (3, 2, 1)
    (failure,) = counts.failures
    assert failure.startswith(f"{broken.run_dir}: CheckpointError: ") and "\n" not in failure
    assert "not a readable checkpoint" in failure
    assert len(evaluations(cache)) == 2 and not (Path(broken.run_dir) / "eval.json").exists()


@pytest.mark.slow
def test_reproduce_cli_through_ray(tmp_path):
    """The command line, with its own local Ray instance (2 CPUs), started and shut down."""
    cache = tmp_path / "cache"
    argv = ["--quick", "--settings", "hc_go", "--variants", "const_vel", "--backend", "ray"]
    argv += ["--jobs", "2", "--out-dir", str(cache)]
    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / "reproduce.py"), *argv],
        capture_output=True,
        text=True,
        env=tool_env(),
        timeout=900,  # seconds of work, but it shares 2 cores with other test files
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "1 runs (1 trained, 0 resumed, 0 reused, 0 failed)" in done.stdout
    assert (cache / "RESULTS.md").is_file() and len(evaluations(cache)) == 1


@pytest.mark.slow
def test_ctrl_c_cancels_a_ray_sweep_and_the_rerun_resumes(tmp_path):
    """Ctrl-C to the process group (the command, its Ray instance; the workers have their own
    groups) once a run has finished an epoch: exit 130, one line, no result; the same command
    then resumes every run that had saved a last.pt and trains the other (if its worker had not
    finished an epoch: the signal does not wait for the second worker, so a slow start cannot
    let the first run finish before it)."""
    cache = tmp_path / "cache"
    argv = ["--quick", "--settings", "hc_go", "--variants", "ours", "--seeds", "2"]
    epochs = 6  # the signal comes after the first epoch of the first run
    argv += ["--epochs", str(epochs), "--backend", "ray", "--jobs", "2", "--out-dir", str(cache)]
    command = [sys.executable, str(REPO_ROOT / "tools" / "reproduce.py"), *argv]
    env = tool_env()
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + 300
    while not list(cache.glob("runs/*/ours/*/last.pt")):
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"no epoch finished in time: {process.communicate()[1][-2000:]}")
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 130, err[-2000:]
    assert err.splitlines()[-1].startswith("error: interrupted; finished runs are cached")
    assert out == "" and "Traceback" not in err and not list(cache.rglob("eval.json"))
    stopped = len(list(cache.glob("runs/*/ours/*/last.pt")))  # 1 or 2
    # generous: a loaded machine ran the resumed runs past 300 s (when Ray's workers ran niced)
    resumed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=1200)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    summary = f"2 runs ({2 - stopped} trained, {stopped} resumed, 0 reused, 0 failed)"
    assert summary in resumed.stdout
    for metrics in cache.glob("runs/*/ours/*/metrics.jsonl"):
        done = [json.loads(line)["epoch"] for line in metrics.read_text().splitlines()]
        assert done == list(range(1, epochs + 1))  # each epoch once: none lost, none repeated


def test_missing_ray_is_one_line_exit_2(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(RayUnavailableError, match=r"pip install -e '\.\[ray\]'"):
        with ray_session():
            pass
    out = tmp_path / "x.h5"
    argv = [
        "--scenario",
        "halting_car_v0",
        "--num-major",
        "2",
        "--backend",
        "ray",
        "--out",
        str(out),
    ]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("generate.py").main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the ray backend needs Ray" in err
    assert not out.exists()


def test_missing_ray_stops_a_ray_sweep_with_one_line_exit_2(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)
    cache = tmp_path / "cache"
    argv = ["--quick", "--settings", "hc_go", "--backend", "ray", "--out-dir", str(cache)]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("reproduce.py").main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the ray backend needs Ray" in err
    assert not list(cache.rglob("*.h5"))  # nothing was made
