"""Reproduce the paper's synthetic experiments: the cache, the jobs and the pool.

Protocol (paper, Sec. V; its definitions are in pipeline.protocol): for every setting one
dataset is generated with dataset seed 0 (so all variants and seeds see the same trajectories);
each trained variant (`ours`, `s_attn`, `nonsmooth`, `average`, `correct`) is trained with
training seeds 0..k-1 and evaluated from its best.pt (lowest validation ADE of the main agents)
on the test split; `const_vel` is evaluated once per setting (deterministic). `reproduce(...)`
runs what the cache lacks and writes the report (pipeline.report).

Cache (`out_dir`): `data/<stem>.h5` per dataset (the stem names every generator input) and
`runs/<stem>/<variant>/seed<k>_ep<E>_<hash>/` per run (train's files plus `eval.json`, written
last and atomically, and for seed 0 of ours and s_attn `scenes.npz`, the predictions of the
figure scenes). A run with its eval.json is reused; a run with last.pt resumes (bit-identical to
an uninterrupted one). Identical inputs share one cache entry. `invocations.jsonl` logs every
invocation that ran jobs (date, command, wall seconds), for the report's wall time. The keys
hash the scenario, model and training configurations (a changed default starts new runs) but
not the code: delete the cache after changing how experts, model or training behave.

Results store (`store`, optional): each finished run's eval.json (and scenes.npz for the
figure runs), no checkpoints, under the same relative path as under `runs/`. A job whose
results are in the cache or the store is not run again; the report reads both. Meant to be
committed, so a protocol can be completed over several sittings or machines. A time budget
(`budget_s`) starts no run after it expires; running ones finish, the rest wait for a rerun.

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
import hashlib
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pipeline.backends import Runner
from pipeline.files import atomic_output
from pipeline.generation import GenerateConfig, UnsafeExpertError, generate_dataset
from pipeline.pool import check_stop
from pipeline.protocol import (
    Protocol,
    ReproductionError,
    Setting,
)
from pipeline.report.records import BASELINES, RunRecord

FIGURE_VARIANTS = ("ours", "s_attn")  # their first seed keeps predictions of the figure scenes
DEFAULT_STORE = "results"  # the results store tools/reproduce.py keeps (tracked: commit it)
INVOCATION_LOG = "invocations.jsonl"  # in the cache: date, command, wall seconds, jobs run
RUN_THREADS = 1  # torch threads of a training/evaluation job: a Ray task asks for this many CPUs
RAY_RETRIES = 1  # a Ray task whose worker dies is run once more; dying twice fails the job


@dataclass(frozen=True)
class DataSpec:
    """The generator inputs of one dataset."""

    scenario: str
    major_case: str
    num_major: int
    num_minor: int
    num_test: int
    seed: int
    scenario_digest: str  # of the scenario's configuration (a changed default changes the key)

    @property
    def stem(self) -> str:
        return (
            f"{self.scenario}_{self.major_case}-major_{self.num_minor}+{self.num_major}"
            f"_test{self.num_test}_seed{self.seed}_{self.scenario_digest}"
        )

    def config(self) -> GenerateConfig:
        """The generator configuration (validated)."""
        return GenerateConfig.for_scenario(
            self.scenario,
            major_case=self.major_case,
            num_major=self.num_major,
            num_minor=self.num_minor,
            num_test=self.num_test,
            seed=self.seed,
        )


@dataclass(frozen=True)
class Job:
    """Train (unless the baseline) and evaluate one (dataset, variant, seed)."""

    data_path: str
    variant: str
    seed: int  # training seed (0 for the baseline: unused)
    epochs: int
    run_dir: str
    save_scenes: bool  # keep predictions of the figure scenes (scenes.npz)
    store_dir: str = ""  # where the results store keeps its eval.json (and scenes.npz); "" none
    preset: str = "paper"  # predictor.config.PRESETS


@dataclass(frozen=True)
class JobOutcome:
    """What became of one job: "trained", "resumed" or "failed" (diverged, raised on a Ray
    worker, or its worker died twice), and its wall time."""

    status: str
    seconds: float
    error: str = ""


# ---------------------------------------------------------------------------------- planning
def digest(value: object) -> str:
    """Short stable hash of a JSON-able value (cache keys)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def data_spec(protocol: Protocol, setting: Setting) -> DataSpec:
    """The dataset a setting uses under a protocol."""
    from scenarios import SCENARIOS

    num_major, num_minor = protocol.counts(setting)
    config = asdict(SCENARIOS[setting.scenario]().config)
    return DataSpec(
        setting.scenario,
        setting.major_case,
        num_major,
        num_minor,
        protocol.num_test,
        protocol.data_seed,
        digest(config),
    )


def run_configs(variant: str, seed: int, epochs: int, preset: str = "paper") -> tuple:
    """(ModelConfig, TrainConfig) of a run: the preset's configuration, one torch thread."""
    from predictor.config import make_configs

    return make_configs(variant, None, preset=preset, seed=seed, epochs=epochs, threads=RUN_THREADS)


def data_path(out_dir: Path, spec: DataSpec) -> Path:
    """Where the cache keeps a dataset."""
    return out_dir / "data" / f"{spec.stem}.h5"


def run_dir(
    out_dir: Path, spec: DataSpec, variant: str, seed: int, epochs: int, preset: str = "paper"
) -> Path:
    """runs/<stem>/<variant>/seed<k>_ep<E>_<digest of the model and training configs>."""
    from predictor.stored_config import config_key

    base = out_dir / "runs" / spec.stem / variant
    if variant in BASELINES:
        return base
    configs = [config_key(c) for c in run_configs(variant, seed, epochs, preset)]
    return base / f"seed{seed}_ep{epochs}_{digest(configs)}"


def setting_jobs(
    protocol: Protocol, setting: Setting, out_dir: Path, store: Path | None = None
) -> list[Job]:
    """The jobs of one setting, in variant then seed order; with a results `store`, each job
    keeps its results under the same relative path there as under out_dir/runs."""
    spec = data_spec(protocol, setting)
    path = str(data_path(out_dir, spec))
    jobs = []
    for variant in protocol.variants:
        for seed in [0] if variant in BASELINES else range(protocol.seeds):
            directory = run_dir(out_dir, spec, variant, seed, protocol.epochs, protocol.preset)
            kept = "" if store is None else str(store / directory.relative_to(out_dir / "runs"))
            save_scenes = variant in FIGURE_VARIANTS and seed == 0
            jobs.append(
                Job(
                    path,
                    variant,
                    seed,
                    protocol.epochs,
                    str(directory),
                    save_scenes,
                    kept,
                    protocol.preset,
                )
            )
    return jobs


def unique(items: list) -> list:
    """Items in first-seen order without repeats (settings may share data or runs)."""
    return list(dict.fromkeys(items))


# ---------------------------------------------------------------------------------- jobs
def ensure_dataset(item: tuple[DataSpec, str]) -> str:
    """Generate the dataset unless the cached file exists; returns "generated" or "reused".

    Raises RuntimeError naming the file if a cached one was made with other inputs or
    generation fails.
    """
    from predictor.format_reader import read_meta

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
    return JobOutcome(status, time.perf_counter() - started)


def train_job(job: Job) -> str:
    """Train the run, or resume it from its last.pt; returns "trained" or "resumed"."""
    from predictor.training import train

    directory = Path(job.run_dir)
    resume = (directory / "last.pt").is_file()
    model_cfg, train_cfg = run_configs(job.variant, job.seed, job.epochs, job.preset)
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
    from predictor.evaluation import evaluate_baseline, evaluate_run

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
        **extra,
    }
    if job.save_scenes:
        rows = figure_scenes(predictions.case, predictions.interaction, len(meta.case_names))
        with atomic_output(directory / "scenes.npz") as temp:
            evaluation.save_predictions(temp, rows)
    info["eval_seconds"] = time.perf_counter() - started
    with atomic_output(directory / "eval.json") as temp:
        temp.write_text(json.dumps({**info, **evaluation.scores}, indent=1) + "\n")


def _train_seconds(metrics: Path) -> float:
    """Training wall time summed over the run's epochs (across resumes)."""
    lines = metrics.read_text().splitlines() if metrics.is_file() else []
    return float(sum(json.loads(line)["seconds"] for line in lines if line.strip()))


# ---------------------------------------------------------------------------------- the cache
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
    """One record per (setting, variant, seed) whose eval.json exists (cache or store)."""
    records = []
    for setting in protocol.settings:
        for job in setting_jobs(protocol, setting, out_dir, store):
            result = read_eval(job)
            if result is not None:
                records.append(RunRecord.from_eval(setting.name, job.variant, job.seed, result))
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
            if job.variant in FIGURE_VARIANTS and job.seed == 0 and read_eval(job) is not None:
                files[job.variant] = str(result_dir(job) / "scenes.npz")
        if set(files) == set(FIGURE_VARIANTS):
            found[setting.name] = files
    return found


@dataclass(frozen=True)
class RunCounts:
    """What an invocation did with the datasets and runs of its protocol."""

    datasets_generated: int
    datasets_reused: int
    runs: int  # every run of the protocol
    reused: int  # runs whose eval.json was cached
    trained: int
    resumed: int
    failed: int
    failures: tuple[str, ...] = ()  # "run_dir: error" of each failed run
    skipped: int = 0  # runs not started because the time budget ran out
    reused_from_store: int = 0  # of `reused`: read from the results store, not the cache
    kept: int = 0  # results copied into the results store by this invocation

    def to_json(self) -> dict:
        return {**asdict(self), "failures": list(self.failures)}


@dataclass(frozen=True)
class Invocation:
    """One logged invocation that ran jobs into the cache."""

    date: str
    command: str
    seconds: float
    runs: int  # jobs run (trained or resumed; const_vel: evaluated)


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
        todo = sorted((job for job in all_jobs if read_eval(job) is None), key=lambda j: j.seed)
        outcomes = run_jobs(runner, todo, deadline)
    from_store = sum(
        1 for job in all_jobs if job not in todo and result_dir(job) == Path(job.store_dir)
    )
    statuses = [o.status if o is not None else "skipped" for o in outcomes]
    kept = sum(keep_result(job) for job in all_jobs)
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


def log_invocation(
    out_dir: Path, command: str, seconds: float, counts: RunCounts
) -> tuple[Invocation, ...]:
    """Append this invocation to the cache's log if it ran any job; return every logged one,
    so a report rebuilt from the cache can still give the wall time spent."""
    path = out_dir / INVOCATION_LOG
    ran = counts.trained + counts.resumed
    if ran:
        now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        entry = Invocation(now, command, round(seconds, 1), ran)
        with open(path, "a") as stream:
            stream.write(json.dumps(asdict(entry)) + "\n")
    if not path.is_file():
        return ()
    lines = path.read_text().splitlines()
    return tuple(Invocation(**json.loads(line)) for line in lines if line.strip())


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
) -> Outcome:
    """Run what the cache in `out_dir` and the results `store` lack and write the report at
    `report` (a .md file; results.json and results/ go beside it). `command` is how the report
    names the invocation. With `budget_s`, no run starts after that many seconds: the running
    ones finish and the report covers what is done. `backend` "local" runs `jobs` processes
    here, "ray" Ray tasks on the cluster at `address` (see the module).

    Raises FileExistsError if the report exists and not `overwrite`, ReproductionError for an
    unusable cache entry, RuntimeError if a dataset cannot be made, RayUnavailableError if Ray
    is asked for but not installed; KeyboardInterrupt leaves every finished run cached.
    """
    from pipeline.report.document import ReportInput, write_report

    if report.exists() and not overwrite:
        raise FileExistsError(f"{report} already exists")
    started = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    report.parent.mkdir(parents=True, exist_ok=True)
    deadline = None if budget_s is None else time.monotonic() + budget_s
    counts = execute(protocol, out_dir, jobs, store, deadline, backend, address)
    history = log_invocation(out_dir, command, time.perf_counter() - started, counts)
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
    figures = write_report(source, report)
    return Outcome(report, figures, counts, time.perf_counter() - started)
