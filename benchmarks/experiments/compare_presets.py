"""Experiment (issue 10): one variant under two presets, side by side, from the results store.

Usage: python benchmarks/experiments/compare_presets.py [--presets agent,agent_zero_cv]
       [--settings hc_go,hc_stop,dm_r0.3] [--variant ours] [--seeds 5] [--epochs 90]
       [--store results]

Reads each run's evaluation from the committed results store (`results/`, as
`tools/reproduce.py` keeps it; nothing is trained) and prints, per setting, case and preset, the
mean over the seeds found of the main-car and all-agent test ADE [m], the attention bar's counts
(seeds with mean weight >= 0.5 on the labelled car in the interaction period and accuracy >= 0.8),
and the p-value of Welch's t-test between the presets on the main-car ADE (as the report's). A
preset whose runs are missing shows the seeds it has. Not run by `make bench`; docs/PREDICTOR.md
has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.stats import ttest_ind

from pipeline.protocol import SETTINGS, Protocol
from pipeline.run_plan import data_spec, run_dir
from predictor.presets import PRESETS

ATTENTION_BAR = (0.5, 0.8)  # issue 10: mean weight, accuracy


def runs_of(protocol: Protocol, setting, store: Path, variant: str) -> list[dict]:
    """The stored evaluations of a variant's seeds under a protocol (missing seeds left out)."""
    spec = data_spec(protocol, setting)
    found = []
    for seed in range(protocol.seeds):
        path = run_dir(Path("cache"), spec, variant, seed, protocol.epochs, protocol.preset)
        evaluation = store / path.relative_to(Path("cache") / "runs") / "eval.json"
        if evaluation.is_file():
            found.append(json.loads(evaluation.read_text()))
    return found


def summary(runs: list[dict]) -> dict:
    """Per case: mean main-car and all-agent ADE and the main-car ADE per seed; the seeds
    meeting the attention bar."""
    cases = runs[0]["main_agents"]["cases"] if runs else {}
    out: dict = {"seeds": [r["seed"] for r in runs], "cases": {}}
    for case in cases:
        main = [r["main_agents"]["cases"][case]["ade"] for r in runs]
        every = [r["all_agents"]["cases"][case]["ade"] for r in runs]
        out["cases"][case] = {"main": main, "main_mean": float(np.mean(main))}
        out["cases"][case]["all_mean"] = float(np.mean(every))
    attention = [r["attention_accuracy"]["overall"] for r in runs]
    out["attention_bar"] = sum(
        (a["mean_weight"] or 0) >= ATTENTION_BAR[0] and (a["accuracy"] or 0) >= ATTENTION_BAR[1]
        for a in attention
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", default="agent,agent_zero_cv", help="two presets")
    parser.add_argument("--settings", default="hc_go,hc_stop,dm_r0.3", help="setting names")
    parser.add_argument("--variant", default="ours", help="trained variant (default ours)")
    parser.add_argument("--seeds", type=int, default=5, help="training seeds 0..seeds-1")
    parser.add_argument("--epochs", type=int, default=90, help="training epochs (default 90)")
    parser.add_argument("--store", type=Path, default=Path("results"), help="results store")
    args = parser.parse_args()
    presets = args.presets.split(",")
    known = {setting.name: setting for setting in SETTINGS}
    wanted = args.settings.split(",")
    if len(presets) != 2 or not set(presets) <= set(PRESETS):
        parser.error(f"--presets needs two of {sorted(PRESETS)}")
    if not set(wanted) <= set(known):
        parser.error(f"unknown settings {sorted(set(wanted) - set(known))}")
    rows = []
    for name in wanted:
        found = {}
        for preset in presets:
            protocol = Protocol(
                (known[name],), (args.variant,), args.seeds, args.epochs, preset=preset
            )
            found[preset] = summary(runs_of(protocol, known[name], args.store, args.variant))
        first, second = (found[p] for p in presets)
        print(
            f"{name}: seeds {first['seeds']} / {second['seeds']}, attention bar "
            f"{first['attention_bar']} / {second['attention_bar']}"
        )
        for case in first["cases"]:
            a, b = first["cases"][case], second["cases"].get(case)
            if b is None:
                continue
            p = float(ttest_ind(a["main"], b["main"], equal_var=False).pvalue)
            print(
                f"  {case}: main {a['main_mean']:.3f} / {b['main_mean']:.3f} (p = {p:.3f}), "
                f"all agents {a['all_mean']:.4f} / {b['all_mean']:.4f}"
            )
            found[presets[1]]["cases"][case]["p_main"] = p
        rows.append({"setting": name, **found})
    print(json.dumps({"presets": presets, "variant": args.variant, "rows": rows}))


if __name__ == "__main__":
    main()
