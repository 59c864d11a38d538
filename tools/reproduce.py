"""Reproduce the paper's synthetic experiments on fresh data and write a report (RESULTS.md).

Examples:
    python tools/reproduce.py                      # the full protocol (days; see below)
    python tools/reproduce.py --settings main --seeds 3 --jobs 2
    python tools/reproduce.py --quick              # tiny smoke version of everything (minutes)
    python tools/reproduce.py --budget-minutes 0 --report docs/RESULTS.md --overwrite  # report only
    python tools/reproduce.py --settings main --backend ray --address HEAD_IP:6379
    python tools/reproduce.py --compare-presets agent_zero_cv,paper@main --seeds 5

The report goes to OUT_DIR/RESULTS.md (default outputs/reproduce/RESULTS.md), with
results.json and the figures (results/) beside it, and there too a viewer page of each main
setting's drawn scenes (view_<setting>.html: one HTML file, opens from disk in a browser);
`--report docs/RESULTS.md --overwrite` replaces the repository's published one.

Protocol (paper, Sec. V; pipeline/reproduction.py): for every setting one dataset is generated
with dataset seed 0 (so all variants and seeds see the same trajectories); each trained variant
(`ours`, `s_attn`, `nonsmooth`, `average`, `correct`) is trained under `--preset` (default
`agent`, this project's model; `paper` is the paper's literal one) with training
seeds 0..k-1 (`--seeds k`, 10 in the paper) for `--epochs` (200) and evaluated from its best.pt
(lowest validation ADE of the main agents) on the test split; the baselines (`const_vel`,
`ridge` and the oracle ridges `ridge_labelled` and `ridge_labelled_relation`, the bar the report
checks Ours against) are evaluated once per setting (deterministic).

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

Presets side by side (`--compare-presets P[,Q]`, `--compare-variants`, default ours): the
variants named are also trained under each preset named, on the same datasets with the same
seeds and epochs, and the report gives them a section of their own (per setting: ADE of the
main cars and of all cars, attention weight, Welch's p against `--preset`) and rows in the
bar table. `P@NAME` runs P only on a setting or group (`paper@main`). The default,
`paper@main`, sets the paper's literal model beside this project's on the main settings (none
when `--preset paper`; `--compare-presets ''` for none). A variant whose configuration a
compared preset leaves unchanged (S-Attn has no highway, so `agent` and `agent_zero_cv` train
the same S-Attn) is one run, trained once.

Results store (`--store`, default results/, none with --quick): each finished run's eval.json
(and, for the figure runs, scenes.npz), no checkpoints, under the same relative path as in the
cache. Commit it: a run found there is not redone, so a protocol can be completed over several
sittings or machines, and the report can be rebuilt from the store alone (the datasets are
regenerated in seconds). `--budget-minutes M` starts no run after M minutes; the running ones
finish, the report covers what is done, and the same command later continues;
`--budget-minutes 0` starts none and rebuilds the report from the store and the cache alone.

Cache (`--out-dir`, default outputs/reproduce): datasets and runs, keyed by every input (see
pipeline/run_plan.py). A run with its eval.json is reused; a run with last.pt resumes
(bit-identical to an uninterrupted one); Ctrl-C stops every job at its next safe point (exit
130) and a rerun of the same command continues. `invocations.jsonl` logs every invocation that
ran jobs (date, command, wall seconds), for the report's wall time: in the results store (so
it is committed with the results), else in the cache. Delete the cache after changing how
experts, model or training behave: the keys hash configurations, not code.

Compiled graph step (`--compile-graph-step yes`, default no): new runs train through
torch.compile of the model's graph step (TrainConfig.compile_graph_step; 1.35-1.7x an
agent-preset epoch, after a first compilation of ~1 min per process and variant with
inductor's disk cache warm, up to ~12 min cold; needs a C++ compiler). The same mathematics
to float rounding, so a compiled run has the eager run's key and row: runs already stored are
reused whichever mode trained them, a resumed run keeps the mode it began with, and each
eval.json records its `graph_step`, which the report counts.

Backends (`--backend`): `local` (default) runs `--jobs` processes here; `ray` runs every job
(and every missing dataset) as a Ray task of one CPU on the cluster at `--address` (default
$RAY_ADDRESS, else a local Ray instance with `--jobs` CPUs), gathered as they finish, with the
same cache, store, budget and report (docs/SCALING.md). The cache is read and written by path:
on a cluster of several machines, --out-dir (and --store) must be on storage every node mounts
at the same path. A job whose worker dies is run once more; a job that raises or dies twice is
reported as failed (exit 1) and the others go on. Ray is an optional extra: pip install -e
'.[ray]'.

Expected wall time, measured on the 2-core AMD EPYC development VM (1 torch thread per job, 2-3
jobs sharing the two cores; epoch times include validation; medians of the committed runs'
train_seconds, 90 epochs, results/): under the agent preset the variants with the sequence loss
(ours, nonsmooth, average, correct) cost ~0.14 s per training scene and epoch (26-35 runs each;
fastest ~0.08-0.12 s; each also spent ~1 min on a first highway fit that training no longer
makes), s_attn ~0.045 s; the paper preset's Ours ~0.29 s (4 runs, 3 jobs on 2 cores). A
200-epoch Ours run would thus take ~25 min on a ratio-0.3 setting (52 training scenes); the
200-epoch runs recorded on dm_r0.3 (results/, trained beside working sessions' tests and
benchmarks) took 3,325-4,178 s for Ours and 1,851-3,579 s for the other variants with the
sequence loss (0.18-0.40 s per scene and epoch: epochs of 9-14 s with only two trainings on
the machine, 20-40 s with a test run beside). The seven settings hold 378 training scenes in
all, so the full protocol (350 runs of the agent preset, 20 of the paper preset) is ~145
job-hours at the 90-epoch rate and up to ~2.5x that on a busy machine: days to weeks with
--jobs 2 here, which is why the 200-epoch protocol of the published report (docs/RESULTS.md)
was gathered over sittings through the results store (results/README.md), and why a shorter
one (5 seeds, 90 epochs) is kept beside it (docs/short_protocol/RESULTS.md). `--quick` took
8 min beside two trainings.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

from pipeline.backends import BACKENDS
from pipeline.cli import FAILED, INTERRUPTED, ArgumentParser, fail, run_main, status
from pipeline.protocol import (
    ALL_VARIANTS,
    DATA_SEED,
    GROUPS,
    NUM_TEST,
    PAPER_EPOCHS,
    PAPER_SEEDS,
    QUICK_EPOCHS,
    QUICK_MAX_MAJOR,
    QUICK_NUM_TEST,
    QUICK_SEEDS,
    REPRODUCTION_COMPARED,
    REPRODUCTION_PRESET,
    SETTING_BY_NAME,
    TRAINED_VARIANTS,
    Protocol,
    ReproductionError,
    pick,
    pick_compared,
)
from pipeline.ray_backend import RayUnavailableError
from pipeline.reproduction import reproduce
from pipeline.result_store import DEFAULT_STORE
from predictor.compiled_step import compiler_missing
from predictor.presets import PRESETS


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
        "--preset",
        default=None,
        choices=sorted(PRESETS),
        help="model and training configuration of the trained variants (predictor/presets.py "
        f"PRESETS; default {REPRODUCTION_PRESET}; paper = the paper's literal version)",
    )
    parser.add_argument(
        "--compare-presets",
        default=None,
        help="comma-separated presets whose runs of --compare-variants the report shows "
        "beside --preset's (same seeds and epochs); PRESET@SETTINGS runs one only on a setting "
        f"or group (default {REPRODUCTION_COMPARED}, none with --preset paper; '' for none)",
    )
    parser.add_argument(
        "--compare-variants",
        default="ours",
        help=f"trained variants run under --compare-presets: {', '.join(TRAINED_VARIANTS)} "
        "(default ours)",
    )
    parser.add_argument(
        "--jobs", type=int, default=2, help="parallel processes, one torch thread each (default 2)"
    )
    parser.add_argument(
        "--compile-graph-step",
        choices=("yes", "no"),
        default="no",
        help="train new runs through torch.compile of the graph step (TrainConfig."
        "compile_graph_step, ~1.35x an agent-preset epoch; needs a C++ compiler): the same "
        "mathematics to float rounding, so the same run keys and rows as eager runs; each "
        "eval.json records its mode and a resumed run keeps its own (default no)",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="local: --jobs processes here (default); ray: one Ray task per job on a cluster, "
        "the same cache and report (pip install -e '.[ray]')",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="with --backend ray: the cluster (default $RAY_ADDRESS, else a local Ray instance "
        "with --jobs CPUs)",
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
        "--report",
        "--results",
        dest="report",
        default=None,
        help="markdown report; results.json and the figures (results/) go beside it, and "
        "figures the previous report listed but this one does not draw are removed "
        "(default OUT_DIR/RESULTS.md; docs/RESULTS.md is the published one)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing report (cached runs are reused regardless)",
    )
    store = parser.add_mutually_exclusive_group()
    store.add_argument(
        "--store",
        default=None,
        help=f"results store: every finished run's eval.json (and figure scenes) is kept "
        f"there, to commit, and runs found there are not redone (default {DEFAULT_STORE}; "
        "none with --quick)",
    )
    store.add_argument("--no-store", action="store_true", help="keep no results store")
    parser.add_argument(
        "--budget-minutes",
        type=float,
        default=None,
        help="start no run after this many minutes: running ones finish, the report covers "
        "what is done, and a rerun continues (default: no limit; 0 starts none and only "
        "rebuilds the report from the store and the cache)",
    )
    return parser.parse_args(argv)


def protocol_from_args(args) -> Protocol:
    """Validate the arguments (exit 2 with one line on a bad value) and build the protocol."""
    preset = args.preset or REPRODUCTION_PRESET
    try:
        names = pick(args.settings, tuple(SETTING_BY_NAME), GROUPS, "setting")
        variants = pick(args.variants, ALL_VARIANTS, {"all": ALL_VARIANTS}, "variant")
        compared = pick(args.compare_variants, TRAINED_VARIANTS, {}, "compared variant")
        presets, compare_only = pick_compared(compared_text(args, preset))
    except ReproductionError as err:
        fail(str(err))
    for other in presets:
        if other not in PRESETS:
            fail(f"unknown compared preset {other!r}; choose from {', '.join(sorted(PRESETS))}")
        if other == preset:
            fail(f"--compare-presets names {other!r}, the report's own --preset")
    seeds = args.seeds if args.seeds is not None else (QUICK_SEEDS if args.quick else PAPER_SEEDS)
    epochs = (
        args.epochs if args.epochs is not None else (QUICK_EPOCHS if args.quick else PAPER_EPOCHS)
    )
    for flag, value in (("--seeds", seeds), ("--epochs", epochs), ("--jobs", args.jobs)):
        if value < 1:
            fail(f"{flag} must be at least 1, got {value}")
    if args.compile_graph_step == "yes" and (why := compiler_missing()) is not None:
        fail(f"--compile-graph-step yes: {why}")
    return Protocol(
        tuple(SETTING_BY_NAME[n] for n in names),
        variants,
        seeds,
        epochs,
        QUICK_NUM_TEST if args.quick else NUM_TEST,
        DATA_SEED,
        args.quick,
        preset,
        presets,
        compared,
        compare_only,
        args.compile_graph_step == "yes",
    )


def compared_text(args, preset: str) -> str:
    """--compare-presets as given, else its default: the paper's preset on the main settings
    beside any other --preset."""
    if args.compare_presets is not None:
        return args.compare_presets
    return "" if preset == "paper" else REPRODUCTION_COMPARED


def store_path(args) -> Path | None:
    """The results store the arguments ask for (None: keep none)."""
    if args.no_store or (args.quick and args.store is None):
        return None
    store = Path(args.store or DEFAULT_STORE)
    if store.exists() and not store.is_dir():
        fail(f"--store {store} exists and is not a directory")
    return store


def output_paths(args) -> tuple[Path, Path]:
    """(cache directory, report path); exit 2 if the report exists without --overwrite."""
    out_dir = Path(
        args.out_dir or ("outputs/reproduce_quick" if args.quick else "outputs/reproduce")
    )
    report = Path(args.report) if args.report else out_dir / "RESULTS.md"
    if report.suffix.lower() != ".md":
        fail(f"--report must name a .md file, got {report}")
    if report.is_dir():
        fail(f"--report {report} is a directory")
    figures = report.with_name("results")
    beside = [report, report.with_name("results.json")]
    beside += [figures] if figures.is_dir() and any(figures.iterdir()) else []
    taken = [path for path in beside if path.exists()]
    if taken and not args.overwrite:
        fail(
            f"{taken[0]} already exists; pass --overwrite to replace the report, results.json "
            "and the figures in results/ beside it (cached runs are reused)"
        )
    if out_dir.exists() and not out_dir.is_dir():
        fail(f"--out-dir {out_dir} exists and is not a directory")
    for flag, folder in (("--out-dir", out_dir), ("--report", report.parent)):
        check_folder(flag, folder)
    return out_dir, report


def check_folder(flag: str, folder: Path) -> None:
    """Exit 2 unless `folder` is, or can be created as, a writable folder: its nearest existing
    ancestor must be a folder we may write in (checked before any run starts)."""
    existing = next(p for p in (folder, *folder.parents) if p.exists())
    if not existing.is_dir():
        fail(f"{flag}: {existing} is a file, so {folder} cannot be a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        fail(f"{flag}: cannot write in {existing}")


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM stops like Ctrl-C


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.address is not None and args.backend != "ray":
        fail("--address needs --backend ray")
    protocol = protocol_from_args(args)
    out_dir, report = output_paths(args)
    store = store_path(args)
    if args.budget_minutes is not None and not args.budget_minutes >= 0:
        fail(f"--budget-minutes must not be negative, got {args.budget_minutes}")
    budget_s = None if args.budget_minutes is None else 60.0 * args.budget_minutes
    command = "python tools/reproduce.py " + " ".join(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # inherited by the spawned workers
    try:
        done = reproduce(
            protocol,
            out_dir,
            report,
            args.jobs,
            command,
            args.overwrite,
            store,
            budget_s,
            backend=args.backend,
            address=args.address,
            status=status,
        )
    except KeyboardInterrupt:
        fail(
            "interrupted; finished runs are cached: run the same command again to resume",
            code=INTERRUPTED,
        )
    except (ReproductionError, RayUnavailableError) as err:
        fail(str(err))
    except FileExistsError as err:  # appeared since output_paths checked
        fail(f"{err}; pass --overwrite to replace the report")
    except (OSError, RuntimeError, ValueError) as err:
        fail(str(err), code=FAILED)
    counts = done.counts
    print(
        f"wrote {report} (+ {report.with_name('results.json').name}, {done.figures} figures in "
        f"{report.parent / 'results'}): {counts.runs} runs ({counts.trained} trained, "
        f"{counts.resumed} resumed, {counts.reused} reused, {counts.failed} failed"
        f"{f', {counts.skipped} left for a later run (budget)' if counts.skipped else ''}), "
        f"{counts.datasets_generated} datasets generated, {counts.datasets_reused} "
        f"reused, in {done.seconds:.1f} s"
    )
    if counts.failed:
        first = counts.failures[0] if counts.failures else "see the report"
        fail(f"{counts.failed} of {counts.runs} runs failed (first: {first})", code=FAILED)


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _interrupt)
    run_main(main)
