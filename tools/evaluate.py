"""Evaluate a trained run or a baseline on a dataset split.

Examples:
    python tools/evaluate.py --run runs/ours_s0 --data data/double_merge.h5
    python tools/evaluate.py --baseline const_vel --data data/double_merge.h5 --out cv.json
    python tools/evaluate.py --baseline ridge --data data/double_merge.h5

Baselines (predictor/baselines.py): `const_vel` (constant velocity); `ridge` (ridge regression
on the agent's own observed history, in its own frame, fitted on the file's train split with
the regularisation chosen by cross-validation); `ridge_nearest`, `ridge_labelled` (oracle) and
`ridge_random` add one other agent's history: the nearest, the labelled one, a random one;
`ridge_labelled_relation` is `ridge_labelled` with one regression per relation to the labelled
agent (ahead or behind it) instead of one per role.

Predicts every scene of the split (default test) from its observed steps, feeding back the mean
of each predicted Gaussian, and reports ADE/FDE [m] per case and overall for the main agents
(the headline: the data's focal agents) and for all agents, plus the attention accuracy
against the oracle labels. Diagnostics (predictor/diagnostics.py, also in the JSON): the
main-agent error per predicted step, for a trained run its teacher-forced one-step error next
to constant velocity's, and how far a main agent's prediction moves when the history of the
car it attends to (its label) is swapped with another scene's, next to the same swap of a
distractor. Writes JSON (default RUN/eval.json) and, with --save-predictions,
the predictions file (.npz, docs/dataset_format.md) for tools/plot.py. A run is evaluated only
on data of the scenario, dt and horizons it was trained on; --allow-scenario-mismatch evaluates
it on another scenario's data (a transfer study: Halting Car v3's model on v2's data) when dt,
the horizons and the agent count match, and the output names both scenarios (printed, and
`scenario_mismatch` in the JSON).

Re-evaluating a run: its eval.json exists, so pass --overwrite to replace it or --out FILE.json
to write beside it. Exit status (docs/CLI.md): 0 evaluated; 2 usage or input error (one line);
1 a write that failed (full disk); 130 interrupted (nothing written).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import torch

from pipeline.cli import (
    INTERRUPTED,
    ArgumentParser,
    check_output,
    fail,
    require_file,
    run_main,
    writing,
)
from predictor.baselines import BASELINES
from predictor.checkpoints import CHECKPOINTS, CheckpointError, ScenarioMismatchError
from predictor.evaluation import Evaluation, evaluate_baseline, evaluate_run
from predictor.forecasting import SAMPLE_METHODS, EvaluationError, SampleSettings
from predictor.wording import Wording
from trajectory_data.format import FormatError


def parse_args(argv: list[str] | None = None):
    parser = ArgumentParser(prog="evaluate.py", description="Evaluate trajectory predictions.")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--run", help="run directory written by tools/train.py")
    source.add_argument(
        "--baseline",
        choices=BASELINES,
        help="a baseline: no training run (ridge ones fit on the train split in seconds)",
    )
    parser.add_argument("--data", required=True, help="dataset file (HDF5, schema 1 or 2)")
    parser.add_argument(
        "--split",
        default="test",
        choices=("train", "val", "test"),
        help="split to evaluate (default test)",
    )
    parser.add_argument(
        "--checkpoint",
        default="best",
        choices=CHECKPOINTS,
        help="which checkpoint of --run (default best)",
    )
    parser.add_argument(
        "--out", default=None, help="JSON output (default RUN/eval.json; none for a baseline)"
    )
    parser.add_argument(
        "--save-predictions",
        default=None,
        metavar="FILE.npz",
        help="also write the predictions for tools/plot.py",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    parser.add_argument(
        "--allow-scenario-mismatch",
        action="store_true",
        help="with --run: evaluate on data of another scenario than the run was trained on, "
        "when dt, the horizons and the agent count match (the output names both scenarios)",
    )
    defaults = SampleSettings()
    parser.add_argument(
        "--samples",
        type=int,
        default=defaults.k,
        metavar="K",
        help=f"sampled futures per agent for minADE_K, minFDE_K and the miss rate (default "
        f"{defaults.k}, the ETH/UCY convention; 0: none)",
    )
    parser.add_argument(
        "--miss-threshold",
        type=float,
        default=defaults.miss_threshold_m,
        metavar="M",
        help=f"[m] a best final error above it is a miss (default {defaults.miss_threshold_m})",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=defaults.seed,
        help=f"seed of the samples (default {defaults.seed})",
    )
    parser.add_argument(
        "--sampler",
        choices=SAMPLE_METHODS,
        default=defaults.method,
        help=f"how a model with one Gaussian per step samples (default {defaults.method}: one "
        "draw per future through every step's Gaussian; rollout: the paper's sampled rollout)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--batch-size", type=int, default=32, help="scenes per forward pass")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    return parser.parse_args(argv)


def check_args(args) -> tuple[Path | None, Path | None]:
    """Validate paths and numbers (exit 2 otherwise); returns (json_out, npz_out)."""
    require_file(args.data, "data file")
    if args.allow_scenario_mismatch and args.run is None:
        fail("--allow-scenario-mismatch applies to --run (a baseline fits on the file itself)")
    if args.batch_size < 1 or args.threads < 1:
        fail("--batch-size and --threads must be at least 1")
    if args.samples < 0 or args.seed < 0:
        fail("--samples and --seed must be at least 0")
    if not (math.isfinite(args.miss_threshold) and args.miss_threshold > 0):
        fail(f"--miss-threshold must be a positive distance in metres, got {args.miss_threshold}")
    out = args.out
    if args.run is not None:
        if not Path(args.run).is_dir():
            what = "is not a directory" if Path(args.run).exists() else "does not exist"
            fail(f"run directory {args.run} {what}")
        require_file(Path(args.run) / f"{args.checkpoint}.pt", "checkpoint")
        out = out or str(Path(args.run) / "eval.json")
    json_out = check_output(out, args.overwrite, "--out FILE.json") if out else None
    npz_out = None
    if args.save_predictions:
        npz_out = check_output(args.save_predictions, args.overwrite, "another --save-predictions")
    if json_out is not None and npz_out is not None and json_out.resolve() == npz_out.resolve():
        fail("--out and --save-predictions name the same file")
    return json_out, npz_out


def format_table(result: dict, case_names: tuple[str, ...], words: Wording | None = None) -> str:
    """Plain-text table: one row per case and overall; with samples, the headline agents'
    best-of-K columns too."""
    who = "main" if words is None or words.agents == "main agents" else "focal"
    scenes = "scenes" if words is None else words.scenes
    k = result["main_agents"]["overall"].get("k")
    header = f"{'case':<12}{'ADE ' + who:>11}{'FDE ' + who:>11}{'ADE all':>10}{'FDE all':>10}"
    if k:
        header += f"{f'minADE{k}':>10}{f'minFDE{k}':>10}{'miss':>8}{'NLL':>10}"
    header += f"{'attn acc':>10}{scenes:>9}"
    rows = [header, "-" * len(header)]

    def cell(value: float | None, width: int = 10, spec: str = ".3f") -> str:
        return f"{'n/a':>{width}}" if value is None else f"{value:>{width}{spec}}"

    for name in (*case_names, "overall"):
        main, every = _row(result["main_agents"], name), _row(result["all_agents"], name)
        accuracy = _row(result["attention_accuracy"], name)["accuracy"]
        line = f"{name:<12}{cell(main['ade'], 11)}{cell(main['fde'], 11)}"
        line += f"{cell(every['ade'])}{cell(every['fde'])}"
        if k:
            line += f"{cell(main['min_ade'])}{cell(main['min_fde'])}"
            # 4 significant digits: a ridge fit's NLL can reach 1e7 nats (a near-singular
            # residual Gaussian) and must not run into the miss column
            line += f"{cell(main['miss_rate'], 8)}{cell(main['nll'], 10, '.4g')}"
        rows.append(f"{line}{cell(accuracy)}{every['scenes']:>9}")
    return "\n".join(rows)


def format_diagnostics(diagnostics: dict | None, words: Wording | None = None) -> str:
    """Lines on why a predictor errs: error curve, one-step error, counterfactual shift."""
    if not diagnostics:
        return ""
    words = words or Wording("main agents", "scenes", "labelled car")
    agent = words.agents[:-1]  # "main agent", "focal agent"

    def metres(value: float | None, unit: float = 1.0, digits: int = 3) -> str:
        return "n/a" if value is None else f"{value * unit:.{digits}f}"

    curve = diagnostics["error_curve"]["main_agents"]
    marks = sorted({0, len(curve) // 3, 2 * len(curve) // 3, len(curve) - 1})
    lines = [
        f"{agent} error [m] at predicted steps "
        + ", ".join(f"{k + 1}: {metres(curve[k])}" for k in marks)
    ]
    if "one_step" in diagnostics:
        one = diagnostics["one_step"]["main_agents"]
        lines.append(
            f"one-step error (teacher forced, {words.agents}): "
            f"{metres(one['model_m'], 1000, 2)} mm vs constant velocity "
            f"{metres(one['const_vel_m'], 1000, 2)} mm"
        )
    cf = diagnostics["counterfactual"]
    if cf["pairs"]:
        lines.append(
            f"counterfactual shift of a {agent}'s prediction: {words.labelled}'s history "
            f"swapped {metres(cf['labelled_m'])} m, a distractor's {metres(cf['distractor_m'])} "
            f"m ({cf['pairs']} pairs)"
        )
    else:
        lines.append("counterfactual shift: n/a (the data names no attended agents)")
    return "\n".join(lines)


def format_faithfulness(block: dict | None) -> str:
    """One line of the attention faithfulness measures that exist (predictor.faithfulness):
    AUROC against the influence, the removal shift, the attention's total variation; empty
    where none does (a baseline on data without influence)."""
    if not block:
        return ""
    parts = []
    if block.get("auroc") is not None:
        parts.append(
            f"attention AUROC {block['auroc']:.3f} against influence > {block['threshold_m']} m "
            f"({block['auroc_agents']} agents)"
        )
    if block.get("robustness_m") is not None:
        ratio = block.get("robustness_ratio")
        share = "" if ratio is None else f", {ratio:.2f} x ADE"
        parts.append(
            f"shift when agents without influence are removed {block['robustness_m']:.3f} m"
            f"{share} ({block['robustness_pairs']} pairs)"
        )
    tv = block.get("attention_tv") or {}
    steps = [(name, tv.get(name)) for name in ("observed", "predicted")]
    if any(value is not None for _, value in steps):
        parts.append(
            "attention TV per step "
            + ", ".join(f"{value:.4f} {name}" for name, value in steps if value is not None)
        )
    return "faithfulness: " + "; ".join(parts) if parts else ""


def _row(group: dict, name: str) -> dict:
    return group["overall"] if name == "overall" else group["cases"][name]


def evaluate(args) -> Evaluation:
    """The evaluation the arguments ask for; exits 2 with one line on bad input, 130 on
    Ctrl-C."""
    progress = not args.no_progress
    try:
        sampling = SampleSettings(args.samples, args.miss_threshold, args.seed, args.sampler)
        if args.baseline:
            return evaluate_baseline(
                args.baseline, args.data, args.split, progress=progress, sampling=sampling
            )
        return evaluate_run(
            args.run,
            args.data,
            args.split,
            args.checkpoint,
            args.batch_size,
            progress=progress,
            allow_scenario_mismatch=args.allow_scenario_mismatch,
            sampling=sampling,
        )
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=INTERRUPTED)
    except ScenarioMismatchError as err:
        fail(
            f"{err}; pass --allow-scenario-mismatch to evaluate it on this data anyway (dt, the "
            "horizons and the agent count match)"
        )
    except (CheckpointError, EvaluationError, FormatError, OSError) as err:
        fail(str(err))


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    json_out, npz_out = check_args(args)
    torch.set_num_threads(args.threads)
    started = time.perf_counter()
    evaluation = evaluate(args)
    result = evaluation.to_dict()
    note = evaluation.mismatch_note()
    if note is not None:
        print(note)
    print(format_table(result, evaluation.meta.case_names, evaluation.words))
    print(format_diagnostics(result.get("diagnostics"), evaluation.words))
    faithful = format_faithfulness(result.get("faithfulness"))
    if faithful:
        print(faithful)
    if npz_out is not None:
        with writing(npz_out) as temp:
            evaluation.save_predictions(temp)
    if json_out is not None:
        with writing(json_out) as temp:
            temp.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    written = ", ".join(str(p) for p in (json_out, npz_out) if p is not None) or "nothing written"
    other = ""
    if evaluation.scenario_mismatch is not None:
        trained, evaluated = evaluation.scenario_mismatch
        other = f" of {evaluated} (trained on {trained})"
    print(
        f"{evaluation.predictor} on {evaluation.scenes} {args.split} {evaluation.words.scenes}"
        f"{other} in "
        f"{time.perf_counter() - started:.1f} s: {evaluation.headline()} ({written})"
    )


if __name__ == "__main__":
    run_main(main)
