"""Experiment (issue 16): does the smoothness prior help at any weight? Ours with beta2 swept.

Usage: python benchmarks/experiments/prior_weight.py --data FILE.h5
           [--beta2 0,0.01,0.1,1,10] [--seeds 5] [--epochs 90] [--preset agent] [--jobs 2]
           [--out-dir outputs/prior_weight]

The paper fixes the attention's total-variation weight beta2 at 0.01, chosen by
cross-validation for its loss. Under the agent preset the means are trained by their
displacement error in metres, so 0.01 may weigh the prior differently. This trains Ours with
each beta2 (0 is the Ours-NonSmooth variant, 0.01 Ours) and every seed 0 .. seeds-1 on one
file, exactly as `tools/reproduce.py --preset PRESET --epochs EPOCHS` trains those variants
(same configs, one torch thread: beta2 0.01 reproduces Ours' eval.json to the last digit),
and evaluates each run's best.pt on the test split. Runs already evaluated in --out-dir are
reused, so it can be stopped and rerun.

Prints one row per beta2 (mean ± standard deviation over seeds): the best epoch's validation
ADE of the main cars (what the paper's cross-validation would choose by), the test main-car
ADE overall and per case, and the attention's mean weight and accuracy on the labelled car
during the interaction period; then the beta2 with the lowest mean validation ADE and Welch's
t-test of its test ADE against beta2 = 0 where both were run. Not run by `make bench`;
docs/short_protocol/results_notes.md has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy import stats
from tqdm import tqdm


def run_dir(out_dir: Path, data: Path, beta2: float, seed: int) -> Path:
    return out_dir / data.stem / f"beta2_{beta2:g}" / f"seed{seed}"


def train_and_evaluate(args: tuple[str, str, float, int, int, str]) -> str:
    """Train Ours with one beta2 and seed, evaluate best.pt on the test split; the run's folder."""
    import torch

    from predictor.evaluation import evaluate_run
    from predictor.presets import make_configs
    from predictor.run_files import atomic_write_text
    from predictor.training import train

    data, folder, beta2, seed, epochs, preset = args
    torch.set_num_threads(1)
    directory = Path(folder)
    # beta2 = 0 is the paper's Ours-NonSmooth variant, trained as tools/reproduce.py trains it
    variant, overrides = ("nonsmooth", {}) if beta2 == 0 else ("ours", {"beta2": beta2})
    model_cfg, train_cfg = make_configs(
        variant, None, preset=preset, seed=seed, epochs=epochs, threads=1, **overrides
    )
    resume = (directory / "last.pt").is_file()
    train(
        data, model_cfg, train_cfg, directory, resume=resume, overwrite=not resume, progress=False
    )
    result = evaluate_run(directory, data).to_dict()
    atomic_write_text(json.dumps(result, indent=2, allow_nan=False) + "\n", directory / "eval.json")
    return folder


def best_validation_ade(directory: Path) -> float:
    """Validation main-car ADE of the epoch best.pt was saved at (metrics.jsonl)."""
    rows = [json.loads(line) for line in (directory / "metrics.jsonl").read_text().splitlines()]
    best = [row for row in rows if row.get("best")]
    return float(best[-1]["val"]["ade_main"])


def read_run(directory: Path) -> dict:
    result = json.loads((directory / "eval.json").read_text())
    main = result["main_agents"]
    attention = result["attention_accuracy"]["overall"]
    return {
        "val_ade": best_validation_ade(directory),
        "test_ade": main["overall"]["ade"],
        **{f"test_ade_{case}": row["ade"] for case, row in main["cases"].items()},
        "weight": attention["mean_weight"],
        "accuracy": attention["accuracy"],
    }


def mean_std(values: list[float]) -> str:
    if not values:
        return "n/a"
    return f"{np.mean(values):.3f} ± {np.std(values, ddof=1) if len(values) > 1 else 0.0:.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, type=Path, help="dataset file (.h5)")
    parser.add_argument("--beta2", default="0,0.01,0.1,1,10", help="comma-separated weights")
    parser.add_argument("--seeds", type=int, default=5, help="training seeds 0 .. N-1")
    parser.add_argument("--epochs", type=int, default=90, help="training epochs")
    parser.add_argument("--preset", default="agent", help="predictor/presets.py PRESETS")
    parser.add_argument("--jobs", type=int, default=2, help="parallel processes (1 thread each)")
    parser.add_argument("--out-dir", type=Path, default=Path("outputs/prior_weight"))
    args = parser.parse_args()
    if not args.data.is_file():
        parser.error(f"--data {args.data} is not a file")
    try:
        weights = [float(v) for v in args.beta2.split(",")]
    except ValueError:
        parser.error(f"--beta2 must be comma-separated numbers, got {args.beta2!r}")
    if any(not math.isfinite(w) or w < 0 for w in weights) or args.seeds < 1 or args.jobs < 1:
        parser.error("--beta2 values must be finite and >= 0, --seeds and --jobs >= 1")
    runs = {
        (w, s): run_dir(args.out_dir, args.data, w, s) for w in weights for s in range(args.seeds)
    }
    todo = [
        (str(args.data), str(d), w, s, args.epochs, args.preset)
        for (w, s), d in runs.items()
        if not (d / "eval.json").is_file()
    ]
    if todo:
        with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
            for _ in tqdm(pool.map(train_and_evaluate, todo), total=len(todo), file=sys.stderr):
                pass
    table = {w: [read_run(runs[w, s]) for s in range(args.seeds)] for w in weights}
    cases = sorted(k for k in table[weights[0]][0] if k.startswith("test_ade_"))
    header = ["beta2", "val ADE", "test ADE", *(c.removeprefix("test_ade_") for c in cases)]
    print("| " + " | ".join(header + ["weight", "accuracy"]) + " |")
    print("|" + "---|" * (len(header) + 2))
    summary = {}
    for w, rows in table.items():
        keys = ["val_ade", "test_ade", *cases, "weight", "accuracy"]
        cells = [mean_std([row[k] for row in rows]) for k in keys]
        print(f"| {w:g} | " + " | ".join(cells) + " |")
        summary[f"{w:g}"] = {k: [row[k] for row in rows] for k in keys}
    chosen = min(weights, key=lambda w: np.mean([row["val_ade"] for row in table[w]]))
    line = f"lowest mean validation ADE: beta2 = {chosen:g}"
    if 0.0 in table and chosen != 0.0 and args.seeds > 1:
        test = stats.ttest_ind(
            [row["test_ade"] for row in table[chosen]],
            [row["test_ade"] for row in table[0.0]],
            equal_var=False,
        )
        line += f"; its test ADE against beta2 = 0: Welch p = {test.pvalue:.3f}"
    print(line)
    print(json.dumps({"data": str(args.data), "seeds": args.seeds, "chosen": chosen, **summary}))


if __name__ == "__main__":
    main()
