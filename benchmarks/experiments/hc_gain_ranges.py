"""Experiment (issue 11): what keeps Halting Car v1's `stop` gain low at the paper's size?

Usage: python benchmarks/experiments/hc_gain_ranges.py VARIANT [--seeds 5] [--num-major 50]
       [--num-minor 15] [--grouping role]

At the paper's size (50 `stop` + 15 `go` train + val) the follower's interaction gain in the
`stop` case is a median 22 % (docs/scenarios.md), below issue 11's 30 %, while 200 + 200 gives
55 %. This changes one group of the expert's random ranges at a time (`VARIANTS`, fields of
`scenarios.ReactiveHaltingCarConfig`) to see which, if any, sets that gain:

- `v1`: the scenario as it is;
- `fixed_resume`: the leader's hidden future fixed (stop 1.5 s, resume 2.5 m/s^2), so what
  the follower does after the leader stands is no longer a draw that no history shows;
- `fixed_resume_delay`: the same and the follower's reaction delay fixed at 0.6 s (2 steps);
- `wide_brake`: the leader's observed braking spread wider (onset 0.9-3.0 s, deceleration
  1.5-6 m/s^2), so more of the follower's future varies with what the leader shows;
- `late_brake`: the leader brakes late in the observed window (2.4-3.0 s), the follower reacts
  0.9 s later (after the window), and the leader's stop (1.5 s) and resume (2.5 m/s^2) are
  fixed: only the leader's history can show that, when and how hard the follower will brake
  (these are `halting_car_v2`'s ranges); `late_brake_random_resume` keeps v1's stop and resume
  draws, `late_brake_later` starts the braking at 2.7-3.0 s, `late_brake_fixed_follower` also
  fixes the follower's time headway (1.6 s) and initial gap (the IDM equilibrium);
- `late_brake_fixed_decel`: `late_brake` with the leader's deceleration fixed at 4 m/s^2, so
  its observed acceleration is the same in every `stop` scene; `late_brake_fixed_speed` fixes
  the cruise (10 m/s) instead, `late_brake_fixed_speed_decel` both, and
  `late_brake_narrow_speed_fixed_decel` fixes the deceleration and draws the cruise from
  9-11 m/s (these are `halting_car_v3`'s ranges, `scenarios.halting_car_fixed_brake`).

For each dataset seed 0 .. seeds-1 a file (100 test trajectories per case) is generated in a
temporary folder with the variant's ranges (the registry entry `halting_car_v1` is replaced in
this process only; the expert's collision safety is not checked here: for `late_brake` the
tests of `halting_car_v2` and `halting_car_v3` check it over 200 seeds per case) and
`predictor.interaction.interaction_gain` is measured with the shared and the banded penalty,
one regression per role (default) or, with `--grouping case`, per case: an oracle grouping that
tells the own-history regression the case too, so what remains is what the leader's history
adds within a case. Printed per penalty and case: gain minimum / median / maximum over the
seeds, the control's median and maximum, the own-history ADE's median, and how many seeds
reach 30 %.
Not run by `make bench`; docs/scenarios.md has the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time

import numpy as np
from gain_seeds import seed_files

import scenarios
from predictor.interaction import interaction_gain
from scenarios.halting_car_fixed_brake import FixedBrakeHaltingCarConfig
from scenarios.halting_car_late import LateBrakeHaltingCarConfig
from scenarios.halting_car_reactive import ReactiveHaltingCar, ReactiveHaltingCarConfig

VARIANTS: dict[str, dict] = {
    "v1": {},
    "fixed_resume": {"stop_duration_s": (1.5, 1.5), "resume_accel_mps2": (2.5, 2.5)},
    "fixed_resume_delay": {
        "stop_duration_s": (1.5, 1.5),
        "resume_accel_mps2": (2.5, 2.5),
        "reaction_delay_s": (0.6, 0.6),
    },
    "wide_brake": {"brake_start_s": (0.9, 3.0), "brake_decel_mps2": (1.5, 6.0)},
    "late_brake": {  # halting_car_v2's ranges (scenarios.halting_car_late)
        name: getattr(LateBrakeHaltingCarConfig(), name)
        for name in ("brake_start_s", "reaction_delay_s", "stop_duration_s", "resume_accel_mps2")
    },
}
LATE = VARIANTS["late_brake"]
VARIANTS.update(
    {
        "late_brake_random_resume": {
            "brake_start_s": LATE["brake_start_s"],
            "reaction_delay_s": LATE["reaction_delay_s"],
        },
        "late_brake_later": {**LATE, "brake_start_s": (2.7, 3.0)},
        "late_brake_fixed_follower": {
            **LATE,
            "time_headway_s": (1.6, 1.6),
            "initial_gap_ratio": (1.0, 1.0),
        },
        "late_brake_fixed_speed": {**LATE, "cruise_speed_mps": (10.0, 10.0)},
        "late_brake_fixed_decel": {**LATE, "brake_decel_mps2": (4.0, 4.0)},
        "late_brake_narrow_speed_fixed_decel": {  # halting_car_v3's ranges
            **LATE,
            "cruise_speed_mps": FixedBrakeHaltingCarConfig().cruise_speed_mps,
            "brake_decel_mps2": FixedBrakeHaltingCarConfig().brake_decel_mps2,
        },
        "late_brake_fixed_speed_decel": {
            **LATE,
            "cruise_speed_mps": (10.0, 10.0),
            "brake_decel_mps2": (4.0, 4.0),
        },
    }
)
PENALTIES = ("shared", "banded")
GAIN_BOUND = 0.30  # issue 11


def patch_ranges(changes: dict) -> None:
    """Make `halting_car_v1` in the registry build its expert with `changes` to the ranges."""
    config = dataclasses.replace(ReactiveHaltingCarConfig(), **changes)

    class Varied(ReactiveHaltingCar):
        def __init__(self, given: ReactiveHaltingCarConfig | None = None) -> None:
            super().__init__(config if given is None else given)

    scenarios.SCENARIOS["halting_car_v1"] = Varied


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variant", choices=tuple(VARIANTS))
    parser.add_argument("--seeds", type=int, default=5, help="dataset seeds 0 .. N-1")
    parser.add_argument("--num-major", type=int, default=50, help="train + val, `stop` case")
    parser.add_argument("--num-minor", type=int, default=15, help="train + val, `go` case")
    parser.add_argument("--grouping", choices=("role", "case"), default="role")
    args = parser.parse_args()
    patch_ranges(VARIANTS[args.variant])
    rows: dict[tuple[str, str], list] = {}
    started = time.time()
    with tempfile.TemporaryDirectory() as folder:
        files = seed_files("halting_car_v1", args.seeds, args.num_major, args.num_minor, folder)
        for path in files:
            for penalty in PENALTIES:
                for row in interaction_gain(path, grouping=args.grouping, penalty=penalty):
                    rows.setdefault((penalty, row.case), []).append(row)
    for (penalty, case), found in sorted(rows.items()):
        gains = np.array([row.gain for row in found])
        controls = np.array([row.control for row in found])
        own = np.array([row.own for row in found])
        print(
            f"{args.variant} {args.num_major}+{args.num_minor} {args.grouping} {penalty:<7}"
            f"{case:<5} gain "
            f"{gains.min():.0%} / {np.median(gains):.0%} / {gains.max():.0%}  control median "
            f"{np.median(controls):+.1%} max {controls.max():+.1%}  own ADE median "
            f"{np.median(own):.2f} m  seeds >= 30 %: {(gains >= GAIN_BOUND).sum()} of {len(gains)}"
        )
    print(f"{time.time() - started:.0f} s")


if __name__ == "__main__":
    main()
