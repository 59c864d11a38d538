"""The results store and the invocation log (pipeline.result_store, pipeline.reproduction):
finished runs kept in the store as they finish, cached results checked before use, a report
rebuilt from the store in a fresh cache, a spent time budget, and the log of invocations. The
--quick smoke run and the rest of tools/reproduce.py are test_reproduce.py's."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from conftest import run_tool

from pipeline import reproduction, result_store, run_plan
from pipeline.protocol import SETTING_BY_NAME, Protocol, ReproductionError


def run_reproduce(*args: str):
    started = time.perf_counter()
    done = run_tool("reproduce.py", *args, timeout=1200)
    return done, time.perf_counter() - started


def test_a_finished_run_is_kept_in_the_store_before_the_invocation_ends(tmp_path, monkeypatch):
    """run_job copies its results into the store as soon as it has evaluated (so a sitting's
    finished runs can be committed while others train); the evaluation is stubbed here, the
    copying is the store's own (tested above)."""
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol((setting,), ("const_vel",), 1, 3)
    store = tmp_path / "store"
    job = run_plan.setting_jobs(protocol, setting, tmp_path / "cache", store)[0]

    def evaluate(job):
        Path(job.run_dir).mkdir(parents=True, exist_ok=True)
        (Path(job.run_dir) / "eval.json").write_text(
            json.dumps({"variant": job.variant, "seed": 0})
        )

    monkeypatch.setattr(reproduction, "evaluate_job", evaluate)
    outcome = reproduction.run_job(job)
    assert outcome.status == "trained" and outcome.kept
    kept = Path(job.store_dir) / "eval.json"
    assert json.loads(kept.read_text()) == {"variant": "const_vel", "seed": 0}
    assert not reproduction.run_job(job).kept  # already in the store: not copied again


def test_cached_results_are_checked_before_use(tmp_path):
    setting = SETTING_BY_NAME["hc_go"]
    protocol = Protocol((setting,), ("ours",), 1, 3)
    job = run_plan.setting_jobs(protocol, setting, tmp_path)[0]
    assert result_store.read_eval(job) is None  # not run yet
    Path(job.run_dir).mkdir(parents=True)
    (Path(job.run_dir) / "eval.json").write_text("{not json")
    with pytest.raises(ReproductionError, match="cannot read cached"):
        result_store.read_eval(job)
    (Path(job.run_dir) / "eval.json").write_text(json.dumps({"variant": "s_attn", "seed": 0}))
    with pytest.raises(ReproductionError, match="is not the result of"):
        result_store.read_eval(job)
    (Path(job.run_dir) / "eval.json").write_text(json.dumps({"variant": "ours", "seed": 0}))
    assert result_store.read_eval(job) is None  # seed 0 of ours also needs its scenes.npz
    (Path(job.run_dir) / "scenes.npz").write_bytes(b"")
    assert result_store.read_eval(job) == {"variant": "ours", "seed": 0}


STORE_ARGS = (
    *("--quick", "--settings", "main", "--variants", "ours,const_vel", "--seeds", "1"),
    *("--compare-presets", ""),  # no compared preset: the store's runs are these four
)


def test_results_store_rebuilds_the_report_in_a_fresh_cache_and_budget_leaves_runs(tmp_path):
    """Runs kept in the store are not redone from another cache (as on another machine with the
    committed store); the report's numbers are the same. A spent budget starts no run."""
    store = tmp_path / "store"
    first, _ = run_reproduce(*STORE_ARGS, "--out-dir", str(tmp_path / "a"), "--store", str(store))
    assert first.returncode == 0, first.stderr[-2000:]
    kept = sorted(p.relative_to(store).as_posix() for p in store.rglob("*") if p.is_file())
    assert len([k for k in kept if k.endswith("eval.json")]) == 4  # 2 settings x (ours, cv)
    assert len([k for k in kept if k.endswith("scenes.npz")]) == 2  # ours seed 0: figure scenes
    assert not any(k.endswith(".pt") for k in kept)  # no checkpoints

    second, _ = run_reproduce(*STORE_ARGS, "--out-dir", str(tmp_path / "b"), "--store", str(store))
    assert second.returncode == 0, second.stderr[-2000:]
    assert "4 runs (0 trained, 0 resumed, 4 reused, 0 failed)" in second.stdout
    assert not list((tmp_path / "b").rglob("*.pt"))
    results = [json.loads((tmp_path / d / "results.json").read_text()) for d in ("a", "b")]
    assert results[0]["runs"] == results[1]["runs"]
    assert results[0]["aggregates"] == results[1]["aggregates"]
    assert results[1]["counts"]["reused_from_store"] == 4
    logged = (store / "invocations.jsonl").read_text().splitlines()  # committed with the results
    assert len(logged) == 1 and json.loads(logged[0])["runs"] == 4
    assert not (tmp_path / "a" / "invocations.jsonl").exists()
    assert "Training invocations logged: 1," in (tmp_path / "b" / "RESULTS.md").read_text()

    spent, _ = run_reproduce(*STORE_ARGS, "--out-dir", str(tmp_path / "c"), "--budget-minutes", "0")
    assert spent.returncode == 0, spent.stderr[-2000:]
    assert (
        "0 trained, 0 resumed, 0 reused, 0 failed, 4 left for a later run (budget)" in spent.stdout
    )
    assert not list((tmp_path / "c").rglob("eval.json"))
    assert "not started: time budget" in (tmp_path / "c" / "RESULTS.md").read_text()


def test_invocation_log_reads_store_and_cache_once_each_and_rejects_a_bad_line(tmp_path):
    store, cache = tmp_path / "store", tmp_path / "cache"
    ran = reproduction.RunCounts(0, 1, runs=3, reused=1, trained=1, resumed=1, failed=0)
    idle = reproduction.RunCounts(0, 1, runs=3, reused=3, trained=0, resumed=0, failed=0)
    first = reproduction.log_invocation(cache, None, "no store", 60.0, ran)
    assert [(e.command, e.runs) for e in first] == [("no store", 2)]
    store.mkdir()
    (store / "invocations.jsonl").write_text((cache / "invocations.jsonl").read_text())  # a copy
    both = reproduction.log_invocation(cache, store, "with store", 30.0, ran)
    assert [e.command for e in both] == ["no store", "with store"]  # the copy counted once
    assert len((store / "invocations.jsonl").read_text().splitlines()) == 2
    assert len((cache / "invocations.jsonl").read_text().splitlines()) == 1
    assert reproduction.log_invocation(cache, store, "nothing ran", 1.0, idle) == both
    with open(store / "invocations.jsonl", "a") as stream:
        stream.write("{not json\n")
    with pytest.raises(ReproductionError, match=r"invocations.jsonl, line 3: not an invocation"):
        reproduction.log_invocation(cache, store, "nothing ran", 1.0, idle)
