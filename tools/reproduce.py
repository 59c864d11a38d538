"""Reproduce the paper's synthetic experiments on fresh data and write docs/RESULTS.md.

Examples:
    python tools/reproduce.py                      # the full protocol (hours; see below)
    python tools/reproduce.py --settings main --seeds 3 --jobs 2
    python tools/reproduce.py --quick              # tiny smoke version of everything (~1-2 min)

Protocol (paper, Sec. V): for every setting one dataset is generated with dataset seed 0 (so
all variants and seeds see the same trajectories); each trained variant (`ours`, `s_attn`,
`nonsmooth`, `average`, `correct`) is trained with training seeds 0..k-1 (`--seeds k`, 10 in
the paper) for `--epochs` (200) and evaluated from its best.pt (lowest validation ADE of the main
agents) on the test split; `const_vel` is evaluated once per setting (deterministic).

| setting     | scenario     | major case | minor + major (train + val) |
|-------------|--------------|------------|-----------------------------|
| `dm_r0.3`   | double_merge | major      | 15 + 50 (ratio 0.3)         |
| `dm_r0.8`   | double_merge | major      | 40 + 50 (ratio 0.8)         |
| `dm_3+10`   | double_merge | major      | 3 + 10 (size study)         |
| `dm_15+30`  | double_merge | major      | 15 + 30 (size study)        |
| `dm_30+100` | double_merge | major      | 30 + 100 (size study)       |
| `hc_stop`   | halting_car  | stop       | 15 + 50 (ratio 0.3)         |
| `hc_go`     | halting_car  | go         | 15 + 50 (ratio 0.3)         |

Groups for `--settings`: `main` (dm_r0.3, hc_stop), `ratio`, `size`, `halting`, `all`.
Every setting has 50 test trajectories per case and a 20 % validation split.

Cache (`--out-dir`, default outputs/reproduce): `data/<stem>.h5` per dataset (the stem names
every generator input) and `runs/<stem>/<variant>/seed<k>_ep<E>_<hash>/` per run (train's
files plus `eval.json`, written last and atomically, and for seed 0 of ours and s_attn
`scenes.npz`, the predictions of the figure scenes). A run with its eval.json is reused; a run
with last.pt resumes (bit-identical to an uninterrupted one); Ctrl-C stops cleanly and a rerun
of the same command continues. Identical inputs share one cache entry. `invocations.jsonl`
logs every invocation that ran jobs (date, command, wall seconds), for the report's wall time.
The keys hash the scenario, model and training configurations (a changed default starts new
runs) but not the code: delete the cache after changing how experts, model or training behave.

Expected wall time, measured on the 2-core AMD EPYC development VM (1 torch thread, other work
running; epoch times include validation): the variants with the sequence loss (ours,
nonsmooth, average, correct) cost ~0.046 s per training scene and epoch, s_attn ~0.019 s
(dm_r0.3, 52 training scenes: ~2.4 s vs ~1.0 s per epoch; dm_30+100, 104 scenes: ~4.7 s vs
~2.0 s). A 200-epoch run thus takes ~8 min (ours) / ~3.5 min (s_attn) on a ratio-0.3 setting and
~16 / ~7 min on dm_30+100; evaluation takes seconds. The seven settings hold 378 training scenes
in all, so the full protocol (350 runs) is ~43 CPU-hours: ~22-26 h with --jobs 2 on two free
cores. `--settings main` (100 runs) ~6 h; `--quick` ~1 min. Measured: `--settings main --seeds 5
--epochs 100 --jobs 2` took 94 min (52 runs).
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import io
import json
import multiprocessing
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.cli import ArgumentParser, atomic_output, fail

TRAINED_VARIANTS = ("ours", "s_attn", "nonsmooth", "average", "correct")
BASELINE = "const_vel"
ALL_VARIANTS = (*TRAINED_VARIANTS, BASELINE)
FIGURE_VARIANTS = ("ours", "s_attn")  # their first seed keeps predictions of the figure scenes
DATA_SEED = 0  # one dataset per setting, fixed: seeds vary only the training
NUM_TEST = 50  # test trajectories per case (paper)
PAPER_EPOCHS, PAPER_SEEDS = 200, 10
QUICK_EPOCHS, QUICK_SEEDS, QUICK_NUM_TEST = 1, 2, 5
INVOCATION_LOG = "invocations.jsonl"  # in OUT_DIR: date, command, wall seconds, jobs run
QUICK_MAX_MAJOR = 10  # --quick shrinks every setting to at most 10 major trajectories
QUICK_MIN_MINOR = 2


@dataclass(frozen=True)
class Setting:
    """One experimental setting: a scenario, its major case and its training-pool sizes."""

    name: str
    scenario: str  # key of scenarios.SCENARIOS
    major_case: str
    num_major: int  # major-case trajectories, training + validation
    num_minor: int  # minor-case trajectories, training + validation
    group: str  # "ratio", "size" or "halting": the paper figure it belongs to
    title: str


SETTINGS = (
    Setting("dm_r0.3", "double_merge", "major", 50, 15, "ratio", "Double Merge, minor ratio 0.3"),
    Setting("dm_r0.8", "double_merge", "major", 50, 40, "ratio", "Double Merge, minor ratio 0.8"),
    Setting("dm_3+10", "double_merge", "major", 10, 3, "size", "Double Merge, 3 minor + 10 major"),
    Setting(
        "dm_15+30", "double_merge", "major", 30, 15, "size", "Double Merge, 15 minor + 30 major"
    ),
    Setting(
        "dm_30+100", "double_merge", "major", 100, 30, "size", "Double Merge, 30 minor + 100 major"
    ),
    Setting(
        "hc_stop",
        "halting_car",
        "stop",
        50,
        15,
        "halting",
        "Halting Car, stop major, minor ratio 0.3",
    ),
    Setting(
        "hc_go", "halting_car", "go", 50, 15, "halting", "Halting Car, go major, minor ratio 0.3"
    ),
)
SETTING_BY_NAME = {s.name: s for s in SETTINGS}
GROUPS = {
    "main": ("dm_r0.3", "hc_stop"),
    "ratio": tuple(s.name for s in SETTINGS if s.group == "ratio"),
    "size": tuple(s.name for s in SETTINGS if s.group == "size"),
    "halting": tuple(s.name for s in SETTINGS if s.group == "halting"),
    "all": tuple(SETTING_BY_NAME),
}


@dataclass(frozen=True)
class Protocol:
    """What a reproduction runs (everything that changes results is here or in the settings)."""

    settings: tuple[Setting, ...]
    variants: tuple[str, ...]  # subset of ALL_VARIANTS, canonical order
    seeds: int  # training seeds 0 .. seeds-1
    epochs: int
    num_test: int = NUM_TEST
    data_seed: int = DATA_SEED
    quick: bool = False

    def counts(self, setting: Setting) -> tuple[int, int]:
        """(num_major, num_minor) generated for a setting; --quick caps the major count."""
        if not self.quick or setting.num_major <= QUICK_MAX_MAJOR:
            return setting.num_major, setting.num_minor
        scale = QUICK_MAX_MAJOR / setting.num_major
        return QUICK_MAX_MAJOR, max(QUICK_MIN_MINOR, round(setting.num_minor * scale))


@dataclass(frozen=True)
class DataSpec:
    """Inputs of tools/generate.py for one dataset."""

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

    def argv(self, out: Path) -> list[str]:
        return [
            "--scenario",
            self.scenario,
            "--major-case",
            self.major_case,
            "--num-major",
            str(self.num_major),
            "--num-minor",
            str(self.num_minor),
            "--num-test",
            str(self.num_test),
            "--seed",
            str(self.seed),
            "--out",
            str(out),
        ]


@dataclass(frozen=True)
class Job:
    """Train (unless the baseline) and evaluate one (dataset, variant, seed)."""

    data_path: str
    variant: str
    seed: int  # training seed (0 for the baseline: unused)
    epochs: int
    run_dir: str
    save_scenes: bool  # keep predictions of the figure scenes (scenes.npz)


# ---------------------------------------------------------------------------------- planning
def digest(value: object) -> str:
    """Short stable hash of a JSON-able value (cache keys)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def data_spec(protocol: Protocol, setting: Setting) -> DataSpec:
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


def run_configs(variant: str, seed: int, epochs: int) -> tuple:
    """(ModelConfig, TrainConfig) of a run: the paper's defaults, one torch thread."""
    from predictor.config import make_configs

    return make_configs(variant, None, seed=seed, epochs=epochs, threads=1)


def data_path(out_dir: Path, spec: DataSpec) -> Path:
    return out_dir / "data" / f"{spec.stem}.h5"


def run_dir(out_dir: Path, spec: DataSpec, variant: str, seed: int, epochs: int) -> Path:
    """runs/<stem>/<variant>/seed<k>_ep<E>_<digest of the model and training configs>."""
    from predictor.config import config_to_dict

    base = out_dir / "runs" / spec.stem / variant
    if variant == BASELINE:
        return base
    configs = [config_to_dict(c) for c in run_configs(variant, seed, epochs)]
    return base / f"seed{seed}_ep{epochs}_{digest(configs)}"


def setting_jobs(protocol: Protocol, setting: Setting, out_dir: Path) -> list[Job]:
    """The jobs of one setting, in variant then seed order."""
    spec = data_spec(protocol, setting)
    path = str(data_path(out_dir, spec))
    jobs = []
    for variant in protocol.variants:
        seeds = [0] if variant == BASELINE else range(protocol.seeds)
        for seed in seeds:
            directory = run_dir(out_dir, spec, variant, seed, protocol.epochs)
            jobs.append(
                Job(
                    path,
                    variant,
                    seed,
                    protocol.epochs,
                    str(directory),
                    variant in FIGURE_VARIANTS and seed == 0,
                )
            )
    return jobs


def unique(items: list) -> list:
    """Items in first-seen order without repeats (settings may share data or runs)."""
    return list(dict.fromkeys(items))


# ---------------------------------------------------------------------------------- workers
_INTERRUPTED = False  # set in a worker by its first SIGINT
_IN_JOB = False


def _on_interrupt(signum, frame) -> None:
    """Workers stop their job at the first Ctrl-C (caches stay consistent) and start no other."""
    global _INTERRUPTED
    first = not _INTERRUPTED
    _INTERRUPTED = True
    if first and _IN_JOB:
        raise KeyboardInterrupt


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, _on_interrupt)
    signal.signal(signal.SIGTERM, _on_interrupt)


def ensure_dataset(item: tuple[DataSpec, str]) -> str:
    """Generate the dataset unless the cached file exists; returns "generated" or "reused"."""
    import generate

    spec, path = item
    expected = asdict(generate.config_from_args(generate.parse_args(spec.argv(Path(path)))))
    if Path(path).is_file():
        from predictor.format import read_meta

        stored = read_meta(path).config.get("generator")
        if stored != expected:
            raise RuntimeError(f"cached dataset {path} was made with other inputs; delete it")
        return "reused"
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured), contextlib.redirect_stdout(io.StringIO()):
            generate.main(spec.argv(Path(path)))
    except SystemExit as exit_:
        lines = captured.getvalue().strip().splitlines() or [f"exit status {exit_.code}"]
        raise RuntimeError(f"generating {path} failed: {lines[-1]}") from None
    return "generated"


def run_job(job: Job) -> dict:
    """Train (or resume) and evaluate one run; returns {"status", "seconds"[, "error"]}."""
    global _IN_JOB
    if _INTERRUPTED:
        raise KeyboardInterrupt
    started = time.perf_counter()
    _IN_JOB = True
    try:
        status = "trained"
        if job.variant != BASELINE:
            status = _train(job)
        _evaluate(job)
    except FloatingPointError as err:  # a diverged run: report it, keep the others going
        return {"status": "failed", "error": str(err), "seconds": time.perf_counter() - started}
    finally:
        _IN_JOB = False
    return {"status": status, "seconds": time.perf_counter() - started}


def _train(job: Job) -> str:
    from predictor.training import train

    directory = Path(job.run_dir)
    resume = (directory / "last.pt").is_file()
    model_cfg, train_cfg = run_configs(job.variant, job.seed, job.epochs)
    train(
        job.data_path,
        model_cfg,
        train_cfg,
        directory,
        resume=resume,
        overwrite=not resume,
        progress=False,
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


def _evaluate(job: Job) -> None:
    """Score the run's best.pt (or the baseline) on the test split; eval.json is written last."""
    from predictor.data import TrajectoryDataset, collate_batch
    from predictor.evaluation import (
        Predictions,
        load_model,
        predict_const_vel,
        predict_model,
        save_predictions,
        score,
    )

    started = time.perf_counter()
    directory = Path(job.run_dir)
    directory.mkdir(parents=True, exist_ok=True)
    test = TrajectoryDataset(job.data_path, "test")
    meta, batch = test.meta, test.all()
    info = {
        "variant": job.variant,
        "seed": job.seed,
        "epochs": job.epochs,
        "data": job.data_path,
        "major_case": meta.major_case,
        "case_names": list(meta.case_names),
        "scenes": batch.batch_size,
    }
    if job.variant == BASELINE:
        predictions = predict_const_vel(batch, meta.num_observed)
        info.update(epochs=0, train_seconds=0.0)
    else:
        model, checkpoint = load_model(directory / "best.pt")
        predictions = predict_model(model, batch, meta.num_observed)
        info.update(
            checkpoint="best.pt",
            best_epoch=int(checkpoint["epoch"]),
            train_seconds=_train_seconds(directory / "metrics.jsonl"),
        )
    result = score(predictions, batch, meta.num_observed, meta.case_names)
    if job.save_scenes:
        rows = figure_scenes(test.data.case, test.data.interaction, len(meta.case_names))
        subset = Predictions(predictions.pred_mean[rows], predictions.attention[rows])
        with atomic_output(directory / "scenes.npz") as temp:
            save_predictions(
                temp,
                subset,
                collate_batch([test[i] for i in rows]),
                meta.num_observed,
                meta.dt,
                meta.case_names,
                meta.role_names,
            )
    info["eval_seconds"] = time.perf_counter() - started
    with atomic_output(directory / "eval.json") as temp:
        temp.write_text(json.dumps({**info, **result}, indent=1) + "\n")


def _train_seconds(metrics: Path) -> float:
    """Training wall time summed over the run's epochs (across resumes)."""
    lines = metrics.read_text().splitlines() if metrics.is_file() else []
    return float(sum(json.loads(line)["seconds"] for line in lines if line.strip()))


# ---------------------------------------------------------------------------------- the pool
def run_parallel(function, items: list, jobs: int, desc: str) -> list:
    """function(item) for every item in `jobs` spawned processes; results in item order."""
    results: list = [None] * len(items)
    if not items:
        return results
    context = multiprocessing.get_context("spawn")  # never fork a process that imported torch
    executor = ProcessPoolExecutor(
        min(jobs, len(items)), mp_context=context, initializer=_init_worker
    )
    bar = tqdm(total=len(items), desc=desc, unit="job", file=sys.stderr, dynamic_ncols=True)
    try:
        futures = {executor.submit(function, item): k for k, item in enumerate(items)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            bar.update()
    except BaseException:
        for process in list((getattr(executor, "_processes", None) or {}).values()):
            if process.is_alive():  # let running jobs stop at a safe point
                os.kill(process.pid, signal.SIGINT)
        raise
    finally:
        bar.close()
        executor.shutdown(wait=True, cancel_futures=True)
    return results


# ---------------------------------------------------------------------------------- records
def read_eval(job: Job) -> dict | None:
    """The job's eval.json if it exists and belongs to the job; exit 2 on a foreign one."""
    path = Path(job.run_dir) / "eval.json"
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        fail(f"cannot read cached {path} ({err}); delete it to redo that run")
    want = {"variant": job.variant, "seed": job.seed}
    if any(result.get(k) != v for k, v in want.items()):
        fail(f"cached {path} is not the result of {want}; delete it to redo that run")
    if job.save_scenes and not (Path(job.run_dir) / "scenes.npz").is_file():
        return None  # e.g. evaluated by hand: redo the evaluation to get the figure scenes
    return result


def collect(protocol: Protocol, out_dir: Path) -> list[dict]:
    """One record per (setting, variant, seed) whose eval.json exists."""
    import _report

    records = []
    for setting in protocol.settings:
        for job in setting_jobs(protocol, setting, out_dir):
            result = read_eval(job)
            if result is not None:
                records.append(_report.make_record(setting.name, job.variant, job.seed, result))
    return records


def scene_files(protocol: Protocol, out_dir: Path) -> dict:
    """setting -> {variant: scenes.npz} for settings where every FIGURE_VARIANTS file exists."""
    found = {}
    for setting in protocol.settings:
        spec = data_spec(protocol, setting)
        files = {
            v: run_dir(out_dir, spec, v, 0, protocol.epochs) / "scenes.npz" for v in FIGURE_VARIANTS
        }
        if all(path.is_file() for path in files.values()):
            found[setting.name] = {v: str(path) for v, path in files.items()}
    return found


# ---------------------------------------------------------------------------------- CLI
def parse_args(argv: list[str] | None = None):
    parser = ArgumentParser(prog="reproduce.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--settings",
        default="all",
        help="comma-separated setting or group names: "
        f"{', '.join(SETTING_BY_NAME)}; {', '.join(GROUPS)} (default all)",
    )
    parser.add_argument(
        "--variants",
        default="all",
        help=f"comma-separated: {', '.join(ALL_VARIANTS)}, or all (default all)",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help=f"training seeds 0..k-1 per variant (default {PAPER_SEEDS}, --quick {QUICK_SEEDS})",
    )
    parser.add_argument(
        "--epochs",
        type=int,
        default=None,
        help=f"training epochs (default {PAPER_EPOCHS}, --quick {QUICK_EPOCHS})",
    )
    parser.add_argument(
        "--jobs", type=int, default=2, help="parallel processes, one torch thread each (default 2)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"tiny smoke version: {QUICK_EPOCHS} epoch(s), {QUICK_SEEDS} seeds, "
        f"{QUICK_NUM_TEST} test scenes per case, at most "
        f"{QUICK_MAX_MAJOR} major trajectories",
    )
    parser.add_argument(
        "--out-dir",
        default=None,
        help="cache of datasets and runs (default outputs/reproduce, "
        "--quick outputs/reproduce_quick)",
    )
    parser.add_argument(
        "--results",
        default=None,
        help="markdown report; figures go to results/ beside it "
        "(default docs/RESULTS.md, --quick OUT_DIR/RESULTS.md)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing report (cached runs are reused regardless)",
    )
    return parser.parse_args(argv)


def pick(
    text: str, known: tuple[str, ...], groups: dict[str, tuple[str, ...]], what: str
) -> tuple[str, ...]:
    """Names from a comma list (group names expand), in canonical order; exit 2 if unknown."""
    chosen = set()
    for name in (part.strip() for part in text.split(",")):
        if name in groups:
            chosen.update(groups[name])
        elif name in known:
            chosen.add(name)
        else:
            fail(f"unknown {what} {name!r}; choose from {', '.join((*known, *groups))}")
    return tuple(name for name in known if name in chosen)


def protocol_from_args(args) -> Protocol:
    """Validate the arguments (exit 2 with one line on a bad value) and build the protocol."""
    names = pick(args.settings, tuple(SETTING_BY_NAME), GROUPS, "setting")
    variants = pick(args.variants, ALL_VARIANTS, {"all": ALL_VARIANTS}, "variant")
    seeds = args.seeds if args.seeds is not None else (QUICK_SEEDS if args.quick else PAPER_SEEDS)
    epochs = (
        args.epochs if args.epochs is not None else (QUICK_EPOCHS if args.quick else PAPER_EPOCHS)
    )
    for flag, value in (("--seeds", seeds), ("--epochs", epochs), ("--jobs", args.jobs)):
        if value < 1:
            fail(f"{flag} must be at least 1, got {value}")
    return Protocol(
        tuple(SETTING_BY_NAME[n] for n in names),
        variants,
        seeds,
        epochs,
        QUICK_NUM_TEST if args.quick else NUM_TEST,
        DATA_SEED,
        args.quick,
    )


def output_paths(args) -> tuple[Path, Path]:
    """(cache directory, markdown path); exit 2 if the report exists without --overwrite."""
    out_dir = Path(
        args.out_dir or ("outputs/reproduce_quick" if args.quick else "outputs/reproduce")
    )
    results = Path(args.results or (out_dir / "RESULTS.md" if args.quick else "docs/RESULTS.md"))
    if results.suffix.lower() != ".md":
        fail(f"--results must name a .md file, got {results}")
    if results.is_dir() or (results.exists() and not args.overwrite):
        fail(f"{results} already exists; pass --overwrite to replace it (cached runs are reused)")
    if out_dir.exists() and not out_dir.is_dir():
        fail(f"--out-dir {out_dir} exists and is not a directory")
    return out_dir, results


def execute(protocol: Protocol, out_dir: Path, jobs: int) -> dict:
    """Make the datasets, then train/evaluate every missing run; returns counts."""
    specs = unique([data_spec(protocol, s) for s in protocol.settings])
    items = [(spec, str(data_path(out_dir, spec))) for spec in specs]
    data_status = run_parallel(ensure_dataset, items, jobs, "datasets")
    all_jobs = unique([j for s in protocol.settings for j in setting_jobs(protocol, s, out_dir)])
    # Seed-major order: an interrupted reproduction leaves whole seeds (every setting and
    # variant), so a rerun with a smaller --seeds reports from the cache alone.
    todo = sorted((job for job in all_jobs if read_eval(job) is None), key=lambda j: j.seed)
    outcomes = run_parallel(run_job, todo, jobs, "runs")
    counts = {
        "datasets_generated": data_status.count("generated"),
        "datasets_reused": data_status.count("reused"),
        "runs": len(all_jobs),
        "reused": len(all_jobs) - len(todo),
    }
    for status in ("trained", "resumed", "failed"):
        counts[status] = sum(o["status"] == status for o in outcomes)
    counts["failures"] = [
        f"{job.run_dir}: {o['error']}" for job, o in zip(todo, outcomes) if o["status"] == "failed"
    ]
    counts["job_seconds"] = [o["seconds"] for o in outcomes if o["status"] != "failed"]
    return counts


def log_invocation(out_dir: Path, command: str, seconds: float, counts: dict) -> list[dict]:
    """Append this invocation to OUT_DIR/invocations.jsonl if it trained any run; return every
    logged invocation, so a report rebuilt from the cache can still give the wall time spent."""
    path = out_dir / INVOCATION_LOG
    trained = counts["trained"] + counts["resumed"]  # jobs run (const_vel: evaluated)
    if trained:
        entry = {
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": command,
            "seconds": round(seconds, 1),
            "runs": trained,
        }
        with open(path, "a") as stream:
            stream.write(json.dumps(entry) + "\n")
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM stops like Ctrl-C


def main(argv: list[str] | None = None) -> None:
    import _report

    args = parse_args(argv)
    protocol = protocol_from_args(args)
    out_dir, results = output_paths(args)
    command = "python tools/reproduce.py " + " ".join(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # inherited by the spawned workers
    started = time.perf_counter()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        results.parent.mkdir(parents=True, exist_ok=True)
        counts = execute(protocol, out_dir, args.jobs)
        history = log_invocation(out_dir, command, time.perf_counter() - started, counts)
        records = collect(protocol, out_dir)
        paths = {s.name: str(data_path(out_dir, data_spec(protocol, s))) for s in protocol.settings}
        report = _report.ReportInput(
            protocol=protocol,
            records=records,
            data_paths=paths,
            scene_files=scene_files(protocol, out_dir),
            command=command,
            counts=counts,
            jobs=args.jobs,
            seconds=time.perf_counter() - started,
            history=history,
        )
        figures = _report.write_report(report, results)
    except KeyboardInterrupt:
        fail(
            "interrupted; finished runs are cached: run the same command again to resume", code=130
        )
    except (OSError, RuntimeError, ValueError) as err:
        fail(str(err), code=1)
    seconds = time.perf_counter() - started
    print(
        f"wrote {results} (+ {results.with_name('results.json').name}, {figures} figures in "
        f"{results.parent / 'results'}): {counts['runs']} runs ({counts['trained']} trained, "
        f"{counts['resumed']} resumed, {counts['reused']} reused, {counts['failed']} failed), "
        f"{counts['datasets_generated']} datasets generated, {counts['datasets_reused']} "
        f"reused, in {seconds:.1f} s"
    )
    if counts["failed"]:
        raise SystemExit(1)


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _interrupt)
    main()
