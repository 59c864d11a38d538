"""Reproduce the paper's synthetic experiments: the cache, the jobs and the pool.

Protocol (paper, Sec. V; its definitions are in pipeline.protocol): for every setting one
dataset is generated with dataset seed 0 (so all variants and seeds see the same trajectories);
each trained variant (`ours`, `s_attn`, `nonsmooth`, `average`, `correct`) is trained with
training seeds 0..k-1 and evaluated from its best.pt (lowest validation ADE of the main agents)
on the test split; `const_vel` is evaluated once per setting (deterministic). `reproduce(...)`
runs what the cache lacks and writes the report (pipeline.report).

Cache (`out_dir`): `data/<stem>.h5` per dataset and `runs/<stem>/<variant>/seed<k>_ep<E>_<hash>/`
per run (pipeline.run_plan names them): train's files plus `eval.json`, written last and
atomically, and for seed 0 of ours and s_attn `scenes.npz`, the predictions of the figure
scenes. A run with its eval.json is reused; a run with last.pt resumes (bit-identical to an
uninterrupted one). `invocations.jsonl` logs every invocation that ran jobs (date, command,
wall seconds), for the report's wall time: in the results store when there is one (so the log
is committed with the results it produced), else in the cache; the report reads both. The
keys do not hash the code: delete the cache after changing how experts, model or training
behave.

Results store (`store`, optional; pipeline.result_store): each finished run's eval.json (and
scenes.npz), committed, so a protocol can be completed over several sittings or machines. A
time budget (`budget_s`) starts no run after it expires; running ones finish, the rest wait
for a rerun.

Backends (`backend`): "local" runs `jobs` spawned processes here (pipeline.pool); "ray" runs
each missing dataset and each job as a Ray task of `RUN_THREADS` CPUs on the cluster at
`address` (else RAY_ADDRESS, else a local Ray instance with `jobs` CPUs; pipeline.ray_backend),
handed out as CPUs free up and gathered as they finish. The tasks read and write the cache by
its path, so on a cluster of several machines `out_dir` (and the store) must be on storage that
every node mounts at the same path. A task whose worker dies is run once more
(`RAY_RETRIES`); a job that raises, or dies twice, is reported as failed and the rest go on.
Ray is started only when something is left to run.

Interrupts (pipeline.pool): the workers ignore SIGINT and SIGTERM (a terminal's Ctrl-C reaches
the whole process group); the parent, on any exception (KeyboardInterrupt included), sets a
shared stop event. Each job checks it at safe points: before it starts, before every optimiser
step and before the evaluation, so a stopped run keeps its last completed epoch (last.pt) and no
file is half written; a rerun resumes it. With Ray, Ctrl-C cancels the running tasks (their
workers are killed); every checkpoint is written atomically, so each run keeps its last
completed epoch and a rerun resumes it.
"""

from __future__ import annotations

import datetime
import json
import time
from collections.abc import Callable
from dataclasses import asdict, astuple, dataclass
from pathlib import Path

import numpy as np

from pipeline.backends import Runner
from pipeline.files import atomic_output
from pipeline.generation import UnsafeExpertError, generate_dataset
from pipeline.pool import check_stop
from pipeline.protocol import Protocol, ReproductionError
from pipeline.report.records import BASELINES
from pipeline.report.report_input import Invocation, RunCounts
from pipeline.result_store import (
    collect,
    keep_result,
    read_eval,
    result_dir,
    scene_files,
)
from pipeline.run_plan import (
    RUN_THREADS,
    DataSpec,
    Job,
    data_path,
    data_spec,
    run_configs,
    setting_jobs,
    unique,
    unique_runs,
)

INVOCATION_LOG = "invocations.jsonl"  # store or cache: date, command, wall seconds, jobs run
RAY_RETRIES = 1  # a Ray task whose worker dies is run once more; dying twice fails the job


@dataclass(frozen=True)
class JobOutcome:
    """What became of one job: "trained", "resumed" or "failed" (diverged, raised on a Ray
    worker, or its worker died twice), and its wall time."""

    status: str
    seconds: float
    error: str = ""
    kept: bool = False  # its results were copied into the results store when it finished


# ---------------------------------------------------------------------------------- jobs
def ensure_dataset(item: tuple[DataSpec, str]) -> str:
    """Generate the dataset unless the cached file exists; returns "generated" or "reused".

    Raises RuntimeError naming the file if a cached one was made with other inputs or
    generation fails.
    """
    from trajectory_data.reader import read_meta

    spec, path = item
    check_stop()
    config = spec.config()
    if Path(path).is_file():
        if read_meta(path).config.get("generator") != asdict(config):
            raise RuntimeError(f"cached dataset {path} was made with other inputs; delete it")
        return "reused"
    try:
        generate_dataset(config, path, progress=False)
    except (OSError, UnsafeExpertError) as err:
        raise RuntimeError(f"generating {path} failed: {err}") from None
    return "generated"


def run_job(job: Job) -> JobOutcome:
    """Train (or resume) and evaluate one run; a diverged run is reported, not raised."""
    check_stop()
    started = time.perf_counter()
    try:
        status = "trained" if job.variant in BASELINES else train_job(job)
        check_stop()
        evaluate_job(job)
    except FloatingPointError as err:
        return JobOutcome("failed", time.perf_counter() - started, str(err))
    # into the store now, not when the invocation ends: a sitting's finished runs can be
    # committed while others still train, and survive the invocation being cut off
    kept = keep_result(job)
    return JobOutcome(status, time.perf_counter() - started, kept=kept)


def train_job(job: Job) -> str:
    """Train the run, or resume it from its last.pt; returns "trained" or "resumed"."""
    from predictor.training import train

    directory = Path(job.run_dir)
    resume = (directory / "last.pt").is_file()
    # a resumed run keeps the graph step it began with, so its eval.json names one mode
    compiled = resumed_graph_step(directory) if resume else job.compile_graph_step
    model_cfg, train_cfg = run_configs(job.variant, job.seed, job.epochs, job.preset, compiled)
    train(
        job.data_path,
        model_cfg,
        train_cfg,
        directory,
        resume=resume,
        overwrite=not resume,
        progress=False,
        step_callback=check_stop,
    )
    return "resumed" if resume else "trained"


def figure_scenes(case: np.ndarray, interaction: np.ndarray, num_cases: int) -> list[int]:
    """Per case, the first test scene with an interaction period (else the case's first)."""
    chosen = []
    for k in range(num_cases):
        rows = np.flatnonzero(case == k)
        busy = [int(i) for i in rows if interaction[i].any()]
        if busy or len(rows):
            chosen.append(busy[0] if busy else int(rows[0]))
    return chosen


def evaluate_job(job: Job) -> None:
    """Score the run's best.pt (or the baseline) on the test split; eval.json is written last."""
    from pipeline.report.context import code_version
    from predictor.evaluation import evaluate_baseline, evaluate_run, json_safe

    started = time.perf_counter()
    directory = Path(job.run_dir)
    directory.mkdir(parents=True, exist_ok=True)
    if job.variant in BASELINES:
        evaluation = evaluate_baseline(job.variant, job.data_path, "test")
        extra = {"epochs": 0, "train_seconds": 0.0}
    else:
        evaluation = evaluate_run(directory, job.data_path, "test", "best")
        extra = {
            "checkpoint": "best.pt",
            "best_epoch": evaluation.source.epoch,
            "train_seconds": _train_seconds(directory / "metrics.jsonl"),
            "graph_step": stored_graph_step(directory),
        }
    meta, predictions = evaluation.meta, evaluation.predictions
    info = {
        "variant": job.variant,
        "seed": job.seed,
        "epochs": job.epochs,
        "data": job.data_path,
        "major_case": meta.major_case,
        "case_names": list(meta.case_names),
        "scenes": evaluation.scenes,
        "code": code_version(),
        **extra,
    }
    if evaluation.sampling is not None:  # K, seed, miss threshold and method of the samples
        info["sampling"] = evaluation.sampling
    if job.save_scenes:
        rows = figure_scenes(predictions.case, predictions.interaction, len(meta.case_names))
        with atomic_output(directory / "scenes.npz") as temp:
            evaluation.save_predictions(temp, rows)
    info["eval_seconds"] = time.perf_counter() - started
    with atomic_output(directory / "eval.json") as temp:
        text = json.dumps(json_safe({**info, **evaluation.scores}), indent=1, allow_nan=False)
        temp.write_text(text + "\n")


def resumed_graph_step(run: Path) -> bool:
    """Whether the checkpoint a run resumes from (last.pt) trained with a compiled graph step;
    CheckpointError for an unreadable one, as resuming it would raise."""
    from predictor.checkpoints import read_checkpoint

    return bool(read_checkpoint(run / "last.pt")["train_config"].get("compile_graph_step", False))


def stored_graph_step(run: Path) -> str:
    """How the run in `run` trains its graph step, "compiled" or "eager", from its config.json
    (`TrainConfig.compile_graph_step`; runs from before the switch have none: eager)."""
    stored = json.loads((run / "config.json").read_text())["train"]
    return "compiled" if stored.get("compile_graph_step", False) else "eager"


def _train_seconds(metrics: Path) -> float:
    """Training wall time summed over the run's epochs (across resumes)."""
    lines = metrics.read_text().splitlines() if metrics.is_file() else []
    return float(sum(json.loads(line)["seconds"] for line in lines if line.strip()))


def make_datasets(runner: Runner, items: list[tuple[DataSpec, str]]) -> list[str]:
    """ "generated" or "reused" per dataset: cached files are checked here, the missing ones
    made on the backend; RuntimeError if one cannot be made."""
    from pipeline.ray_backend import TaskFailed

    missing = [item for item in items if not Path(item[1]).is_file()]
    made = iter(runner.map(ensure_dataset, missing, "datasets"))
    statuses = [next(made) if item in missing else ensure_dataset(item) for item in items]
    for (_, path), status in zip(items, statuses):
        if isinstance(status, TaskFailed):
            raise RuntimeError(f"dataset {path} on a Ray worker: {status.error}")
    return statuses


def run_jobs(runner: Runner, todo: list[Job], deadline: float | None) -> list[JobOutcome | None]:
    """Every job's outcome (None: not started before the deadline)."""
    from pipeline.ray_backend import TaskFailed

    outcomes = runner.map(run_job, todo, "runs", deadline)
    return [
        JobOutcome("failed", 0.0, o.error) if isinstance(o, TaskFailed) else o for o in outcomes
    ]


def execute(
    protocol: Protocol,
    out_dir: Path,
    jobs: int,
    store: Path | None = None,
    deadline: float | None = None,
    backend: str = "local",
    address: str | None = None,
) -> RunCounts:
    """Make the datasets, then train/evaluate every run that neither the cache nor the results
    store has (none starts after `deadline`, a time.monotonic() value); every finished run's
    results are kept in the store. `backend` and `address`: see the module."""
    specs = unique([data_spec(protocol, s) for s in protocol.settings])
    items = [(spec, str(data_path(out_dir, spec))) for spec in specs]
    all_jobs = unique(
        [j for s in protocol.settings for j in setting_jobs(protocol, s, out_dir, store)]
    )
    with Runner(backend, jobs, address, RUN_THREADS, RAY_RETRIES) as runner:
        data_status = make_datasets(runner, items)
        # Seed-major order: an interrupted reproduction leaves whole seeds (every setting and
        # variant), so a rerun with a smaller seed count reports from the cache alone.
        missing = [job for job in unique_runs(all_jobs) if read_eval(job) is None]
        todo = sorted(missing, key=lambda j: j.seed)
        outcomes = run_jobs(runner, todo, deadline)
    from_store = sum(
        1 for job in all_jobs if job not in todo and result_dir(job) == Path(job.store_dir)
    )
    statuses = [o.status if o is not None else "skipped" for o in outcomes]
    kept = sum(o is not None and o.kept for o in outcomes)
    kept += sum(keep_result(job) for job in all_jobs)  # any the workers did not keep
    return RunCounts(
        datasets_generated=data_status.count("generated"),
        datasets_reused=data_status.count("reused"),
        runs=len(all_jobs),
        reused=len(all_jobs) - len(todo),
        trained=statuses.count("trained"),
        resumed=statuses.count("resumed"),
        failed=statuses.count("failed"),
        failures=tuple(
            f"{job.run_dir}: {o.error}"
            for job, o in zip(todo, outcomes)
            if o is not None and o.status == "failed"
        ),
        skipped=statuses.count("skipped"),
        reused_from_store=from_store,
        kept=kept,
    )


def read_invocation(path: Path, number: int, line: str) -> Invocation:
    """Line `number` of the invocation log at `path`; ReproductionError if it is not one."""
    try:
        return Invocation(**json.loads(line))
    except (json.JSONDecodeError, TypeError) as err:
        message = f"{path}, line {number}: not an invocation record ({err}); fix or delete it"
        raise ReproductionError(message) from None


def log_invocation(
    out_dir: Path, store: Path | None, command: str, seconds: float, counts: RunCounts
) -> tuple[Invocation, ...]:
    """Append this invocation to the log if it ran any job (the store's log when there is a
    store, else the cache's); return every invocation logged in either, oldest first and each
    once, so a report rebuilt on another machine can still give the wall time spent."""
    ran = counts.trained + counts.resumed
    if ran:
        now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        entry = Invocation(now, command, round(seconds, 1), ran)
        log_dir = store if store is not None else out_dir
        log_dir.mkdir(parents=True, exist_ok=True)
        with open(log_dir / INVOCATION_LOG, "a") as stream:
            stream.write(json.dumps(asdict(entry)) + "\n")
    logged: dict[tuple, Invocation] = {}
    for log_dir in (store, out_dir):
        path = None if log_dir is None else log_dir / INVOCATION_LOG
        if path is not None and path.is_file():
            for number, line in enumerate(path.read_text().splitlines(), start=1):
                if line.strip():
                    entry = read_invocation(path, number, line)
                    logged.setdefault(astuple(entry), entry)
    return tuple(sorted(logged.values(), key=lambda entry: entry.date))


# ---------------------------------------------------------------------------------- the whole
@dataclass(frozen=True)
class Outcome:
    """What `reproduce` did: the report written, its figure count, the runs, the wall time."""

    report: Path
    figures: int
    counts: RunCounts
    seconds: float


def reproduce(
    protocol: Protocol,
    out_dir: Path,
    report: Path,
    jobs: int = 2,
    command: str = "",
    overwrite: bool = False,
    store: Path | None = None,
    budget_s: float | None = None,
    backend: str = "local",
    address: str | None = None,
    status: Callable[[str], None] | None = None,
) -> Outcome:
    """Run what the cache in `out_dir` and the results `store` lack and write the report at
    `report` (a .md file; results.json and results/ go beside it). `command` is how the report
    names the invocation. With `budget_s`, no run starts after that many seconds: the running
    ones finish and the report covers what is done. `backend` "local" runs `jobs` processes
    here, "ray" Ray tasks on the cluster at `address` (see the module). `status(line)` hears of
    the phases without a progress bar (collecting the results, writing the report).

    Raises FileExistsError if the report or results.json beside it exists and not `overwrite`,
    ReproductionError for an unusable cache entry, RuntimeError if a dataset cannot be made,
    RayUnavailableError if Ray is asked for but not installed; KeyboardInterrupt leaves every
    finished run cached.
    """
    from pipeline.report.document import write_report
    from pipeline.report.report_input import ReportInput

    for path in (report, report.with_name("results.json")):
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path} already exists")
    started = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    report.parent.mkdir(parents=True, exist_ok=True)
    deadline = None if budget_s is None else time.monotonic() + budget_s
    counts = execute(protocol, out_dir, jobs, store, deadline, backend, address)
    say = status or (lambda line: None)
    say(f"reproduce: collecting the results of {counts.runs} runs")
    history = log_invocation(out_dir, store, command, time.perf_counter() - started, counts)
    source = ReportInput(
        protocol=protocol,
        runs=collect(protocol, out_dir, store),
        data_paths={
            s.name: str(data_path(out_dir, data_spec(protocol, s))) for s in protocol.settings
        },
        scene_files=scene_files(protocol, out_dir, store),
        command=command,
        counts=counts,
        jobs=jobs,
        seconds=time.perf_counter() - started,
        history=history,
    )
    say(f"reproduce: writing the report, its figures and results.json to {report.parent}")
    figures = write_report(source, report)
    return Outcome(report, figures, counts, time.perf_counter() - started)
