"""Finished runs' results: read from the cache or the results store, and kept in the store.

The results store (optional) holds each finished run's eval.json (and scenes.npz for the
figure runs), no checkpoints, under the same relative path as under the cache's `runs/`. A job
whose results are in the cache or the store is not run again; the report reads both. Meant to
be committed, so a protocol can be completed over several sittings or machines.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.files import atomic_output
from pipeline.protocol import Protocol, ReproductionError
from pipeline.report.records import RunRecord
from pipeline.run_plan import FIGURE_VARIANTS, Job, setting_jobs

DEFAULT_STORE = "results"  # the results store tools/reproduce.py keeps (tracked: commit it)


def result_dir(job: Job) -> Path | None:
    """Where the job's finished results are: its run directory if it has an eval.json, else
    the results store if that has one, else None (the job must run)."""
    for directory in (job.run_dir, job.store_dir):
        if directory and (Path(directory) / "eval.json").is_file():
            return Path(directory)
    return None


def read_eval(job: Job) -> dict | None:
    """The job's eval.json (from the cache, else the results store) if it exists and belongs
    to the job (None: the job must run); ReproductionError for an unreadable or foreign one."""
    directory = result_dir(job)
    if directory is None:
        return None
    path = directory / "eval.json"
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        message = f"cannot read cached {path} ({err}); delete it to redo that run"
        raise ReproductionError(message) from None
    want = {"variant": job.variant, "seed": job.seed}
    if any(result.get(k) != v for k, v in want.items()):
        raise ReproductionError(
            f"cached {path} is not the result of {want}; delete it to redo that run"
        )
    if job.save_scenes and not (directory / "scenes.npz").is_file():
        return None  # e.g. evaluated by hand: redo the evaluation to get the figure scenes
    return result


def keep_result(job: Job) -> bool:
    """Copy a finished job's eval.json (and scenes.npz) from its run directory into the results
    store, atomically, eval.json last; True if something was copied."""
    if not job.store_dir or read_eval(job) is None:
        return False
    source, store = Path(job.run_dir), Path(job.store_dir)
    if not (source / "eval.json").is_file() or (store / "eval.json").is_file():
        return False
    store.mkdir(parents=True, exist_ok=True)
    names = ["scenes.npz"] if job.save_scenes else []
    for name in [*names, "eval.json"]:
        with atomic_output(store / name) as temp:
            temp.write_bytes((source / name).read_bytes())
    return True


def collect(protocol: Protocol, out_dir: Path, store: Path | None = None) -> tuple[RunRecord, ...]:
    """One record per (setting, variant, seed) whose eval.json exists (cache or store); runs
    under a compared preset are named by `Job.record_variant`."""
    records = []
    for setting in protocol.settings:
        for job in setting_jobs(protocol, setting, out_dir, store):
            result = read_eval(job)
            if result is not None:
                records.append(
                    RunRecord.from_eval(setting.name, job.record_variant, job.seed, result)
                )
    return tuple(records)


def scene_files(
    protocol: Protocol, out_dir: Path, store: Path | None = None
) -> dict[str, dict[str, str]]:
    """setting -> {variant: scenes.npz} for settings where every FIGURE_VARIANTS file exists."""
    found = {}
    for setting in protocol.settings:
        jobs = setting_jobs(protocol, setting, out_dir, store)
        files = {}
        for job in jobs:
            if job.save_scenes and read_eval(job) is not None:
                files[job.variant] = str(result_dir(job) / "scenes.npz")
        if set(files) == set(FIGURE_VARIANTS):
            found[setting.name] = files
    return found
