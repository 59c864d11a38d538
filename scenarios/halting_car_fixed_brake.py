"""Halting Car v3: the leader's observed braking says, in one reading, what the follower does.

Version 2 (`scenarios.halting_car_late`) moved the leader's braking late in the observed window
and the follower's reaction after it, so only the leader's history shows the stop. Its leader
still draws its deceleration (2.5-5 m/s^2) and cruising speed (8-12 m/s) per scene, and how far
the follower falls behind constant velocity when the leader stops grows with both (the speed
times the time the stop costs, which grows with the speed over the deceleration). The observed
deceleration is then a graded signal whose product with the speed decides the follower's future,
and a linear read of the leader's history at the paper's size recovers a median 30 % of the
follower's `stop` error (docs/scenarios.md). Version 3 keeps v2's expert and ranges except:

- the leader brakes at a fixed 4 m/s^2 (inside v2's range), so its observed
  acceleration in the last one to three observed steps is the same in every `stop` scene and
  zero in every `go` scene: it tells the case without a product;
- the cruising speed is drawn from 9-11 m/s (v2: 8-12), so the speed's share in the follower's
  `stop` future is smaller.

The per-scene randomness that only the leader's history resolves is whether it stops and when
it starts braking (2.4-3.0 s into the episode, so 1-3 observed steps show it). Labels,
interaction period, layout, distractors, the follower's IDM and its 0.9 s reaction delay are
v2's. The fixed ranges still take their draws, so a v3 plan differs from the v2 plan of the same
seed only in the changed ranges. Why these: `benchmarks/experiments/hc_gain_ranges.py` and
docs/scenarios.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from scenarios.base import Range
from scenarios.halting_car_late import LateBrakeHaltingCar, LateBrakeHaltingCarConfig


@dataclass(frozen=True)
class FixedBrakeHaltingCarConfig(LateBrakeHaltingCarConfig):
    """Halting Car v3 settings: v2's, with a fixed braking deceleration and a narrower cruising
    speed."""

    cruise_speed_mps: Range = (9.0, 11.0)  # v0-v2: 8-12 m/s
    brake_decel_mps2: Range = (4.0, 4.0)  # v1, v2: 2.5-5 m/s^2


class FixedBrakeHaltingCar(LateBrakeHaltingCar):
    """Halting Car v3 (see the module docstring): v1's expert with v3's ranges."""

    name = "halting_car_v3"
    config_class = FixedBrakeHaltingCarConfig
