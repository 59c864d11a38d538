"""Experiment (issue 11): the interaction gain at the paper's size over many dataset seeds.

Usage: python benchmarks/experiments/gain_seeds.py [--seeds 10] [--num-major 50] [--num-minor 15]
       [--penalty shared|banded] [--control random|shuffled] [--major-case CASE]
       [--scenarios double_merge_v1,halting_car_v1]

For each scenario (default the v1 ones) and dataset seed 0 .. seeds-1, generates a file of the
given size (100 test trajectories per case) in a temporary folder and measures
`predictor.interaction`'s gain with one ridge regression per role and per relation to the
labelled car. Prints, per scenario,
grouping and case, the gain and control over the seeds' rows (minimum, median, maximum) and
pooled (ADE sums over all rows), and how many rows meet issue 11's bounds (gain >= 30 %,
control within 3 %); `--penalty banded` gives the other car's features a penalty of their own
(`predictor.interaction`); `--control shuffled` replaces the random car by the labelled car of
another scene, a null control whose spread is the probe's own noise at this size;
`--major-case go` makes Halting Car's `go` the major case (default: each scenario's
`default_major_case`, Double Merge `major`, Halting Car `stop`). Not run by
`make bench`; docs/scenarios.md has the figures.
The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from pipeline.generation import GenerateConfig, generate_dataset
from predictor.interaction import CONTROLS, PENALTIES, GainRow, interaction_gain

SCENARIOS = ("double_merge_v1", "halting_car_v1")  # the default of --scenarios
GROUPINGS = ("role", "relation")  # the groupings docs/scenarios.md reports
GAIN_BOUND, CONTROL_BOUND = 0.30, 0.03  # issue 11: gain >= 30 %, random car within 3 %


def seed_files(
    scenario: str,
    seeds: int,
    num_major: int,
    num_minor: int,
    folder: str | Path,
    major_case: str | None = None,
) -> Iterator[Path]:
    """Generate one file of `scenario` per dataset seed 0 .. seeds-1 in `folder` (100 test
    trajectories per case, `major_case` as `GenerateConfig.for_scenario` takes it) and yield
    each path once it is written."""
    for seed in range(seeds):
        config = GenerateConfig.for_scenario(
            scenario,
            major_case=major_case,
            num_major=num_major,
            num_minor=num_minor,
            num_test=100,
            seed=seed,
        )
        path = Path(folder) / f"{scenario}_{seed}.h5"
        generate_dataset(config, path, workers=1, progress=False)
        yield path


def summary(rows: list[GainRow]) -> dict:
    """Gain and control of rows measured on separate files: spread and pooled."""
    gains = np.array([row.gain for row in rows])
    controls = np.array([row.control for row in rows])
    own = sum(row.own * row.agents for row in rows)
    return {
        "rows": len(rows),
        "gain_min": float(gains.min()),
        "gain_median": float(np.median(gains)),
        "gain_max": float(gains.max()),
        "control_min": float(controls.min()),
        "control_median": float(np.median(controls)),
        "control_max": float(controls.max()),
        "controls_within_3pct": int((np.abs(controls) < CONTROL_BOUND).sum()),
        "gains_over_30pct": int((gains >= GAIN_BOUND).sum()),
        "pooled_gain": 1.0 - sum(row.labelled * row.agents for row in rows) / own,
        "pooled_control": sum(row.random * row.agents for row in rows) / own - 1.0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="dataset seeds 0 .. N-1")
    parser.add_argument("--num-major", type=int, default=50, help="train + val, major case")
    parser.add_argument("--num-minor", type=int, default=15, help="train + val, minor case")
    parser.add_argument(
        "--penalty",
        choices=tuple(PENALTIES),
        default="shared",
        help="ridge penalty of the other car's features (predictor.interaction; default shared)",
    )
    parser.add_argument(
        "--control",
        choices=CONTROLS,
        default="random",
        help="the control's neighbour: a random car, or the labelled car of another scene "
        "(predictor.interaction; default random)",
    )
    parser.add_argument(
        "--major-case",
        default=None,
        help="the major case of every scenario (default: each one's default_major_case)",
    )
    parser.add_argument(
        "--scenarios",
        default=",".join(SCENARIOS),
        help=f"comma-separated registered scenarios (default {','.join(SCENARIOS)})",
    )
    args = parser.parse_args()
    rows: dict[tuple[str, str, str], list[GainRow]] = defaultdict(list)
    with tempfile.TemporaryDirectory() as folder:
        for scenario in args.scenarios.split(","):
            files = seed_files(
                scenario, args.seeds, args.num_major, args.num_minor, folder, args.major_case
            )
            for path in files:
                for grouping in GROUPINGS:
                    for row in interaction_gain(
                        path, grouping=grouping, penalty=args.penalty, control=args.control
                    ):
                        rows[(scenario, grouping, row.case)].append(row)
    results = []
    for (scenario, grouping, case), found in rows.items():
        figures = summary(found)
        results.append({"scenario": scenario, "grouping": grouping, "case": case, **figures})
        print(
            f"{scenario:<16}{grouping:<9}{case:<6} rows {figures['rows']:>3}  gain "
            f"{figures['gain_min']:>5.0%} / {figures['gain_median']:>4.0%} / "
            f"{figures['gain_max']:>4.0%} (pooled {figures['pooled_gain']:.0%})  control "
            f"{figures['control_min']:>+6.1%} / {figures['control_median']:>+5.1%} / "
            f"{figures['control_max']:>+6.1%} (pooled {figures['pooled_control']:+.1%})  "
            f"rows gain >= 30 % {figures['gains_over_30pct']}, control within 3 % "
            f"{figures['controls_within_3pct']}"
        )
    summary_line = {
        "seeds": args.seeds,
        "penalty": args.penalty,
        "control": args.control,
        "major_case": args.major_case,
    }
    print(json.dumps({**summary_line, "results": results}))


if __name__ == "__main__":
    main()
