"""Halting Car v2: only the leader's observed braking tells what the follower will do.

Version 1 (`scenarios.halting_car_reactive`) starts the leader's braking 1.5-2.7 s into the
episode and delays the follower's IDM by 0.6 or 0.9 s, so the follower often starts braking
inside the observed window (which ends at 3.3 s): its own history then shows much of its
reaction, and the leader's adds less (a median gain of 22 % at the paper's size,
docs/scenarios.md). Version 2 keeps v1's expert and changes only its ranges:

- the leader, case `stop`, starts braking 2.4-3.0 s into the episode, so the last one to three
  observed steps show it (deceleration 2.5-5 m/s^2 as in v1);
- the follower's reaction delay is fixed at 0.9 s (3 control steps), so its braking starts at
  or after the end of the observed window: its own history is the same whether the leader
  brakes or not;
- the leader's stop (1.5 s) and resume acceleration (2.5 m/s^2), which nothing observed
  reveals, are fixed (v1: 1-2 s and 2-3 m/s^2).

Labels, interaction period, layout, distractors and episode are v1's. The fixed ranges still
take their draws, so a v2 plan differs from the v1 plan of the same seed only in the changed
ranges. Why these ranges: `benchmarks/experiments/hc_gain_ranges.py` and docs/scenarios.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from scenarios.base import Range
from scenarios.halting_car_reactive import ReactiveHaltingCar, ReactiveHaltingCarConfig


@dataclass(frozen=True)
class LateBrakeHaltingCarConfig(ReactiveHaltingCarConfig):
    """Halting Car v2 settings: v1's, with the braking late in the observed window, the
    follower's reaction after it, and the leader's unobservable stop and resume fixed."""

    brake_start_s: Range = (2.4, 3.0)  # v1: 1.5-2.7 s; the observation ends at 3.3 s
    reaction_delay_s: Range = (0.9, 0.9)  # 3 control steps; v1: 2 or 3
    stop_duration_s: Range = (1.5, 1.5)  # v1: 1-2 s
    resume_accel_mps2: Range = (2.5, 2.5)  # v1: 2-3 m/s^2


class LateBrakeHaltingCar(ReactiveHaltingCar):
    """Halting Car v2 (see the module docstring): v1's expert with v2's ranges."""

    name = "halting_car_v2"
    config_class = LateBrakeHaltingCarConfig
