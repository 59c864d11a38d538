"""The Ray backend (pipeline.ray_backend) on a local Ray instance with 2 CPUs: generation through
Ray writes the same bytes as the local backend, a task whose worker dies is retried, and a
missing Ray is one clear line. Skipped where Ray is not installed (`pip install -e '.[ray]'`;
`make test` installs it)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from conftest import load_tool

from pipeline.generation import GenerateConfig, generate_dataset
from pipeline.ray_backend import RayUnavailableError, map_in_order, ray_session

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def session():
    with ray_session(num_cpus=2) as connected:
        yield connected


def test_generation_through_ray_writes_the_same_bytes(session, tmp_path):
    config = GenerateConfig.for_scenario("halting_car", num_major=6, num_minor=3, num_test=4)
    generate_dataset(config, tmp_path / "local.h5", progress=False)
    generate_dataset(config, tmp_path / "ray.h5", workers=2, progress=False, backend="ray")
    assert (tmp_path / "ray.h5").read_bytes() == (tmp_path / "local.h5").read_bytes()


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


def test_missing_ray_is_one_line_exit_2(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(RayUnavailableError, match=r"pip install -e '\.\[ray\]'"):
        with ray_session():
            pass
    out = tmp_path / "x.h5"
    argv = ["--scenario", "halting_car", "--num-major", "2", "--backend", "ray", "--out", str(out)]
    with pytest.raises(SystemExit) as exit_info:
        load_tool("generate.py").main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the ray backend needs Ray" in err
    assert not out.exists()
