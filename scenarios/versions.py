"""Every scenario family and its versions, in one place (`scenarios.registry` builds on it).

A version is one `Version` entry, numbered by its position (v0, v1, ...). A version that only
changes settings names the changed config fields (`settings`) and keeps the previous
version's code; its environment module, generator choice, docs table row and tests all follow
from the entry. Settings are cumulative: v3 below has v2's settings plus its own.
docs/scenarios.md measures each version (interaction gain) and says why it exists.
"""

from __future__ import annotations

from scenarios.double_merge import DoubleMerge
from scenarios.double_merge_reactive import ReactiveDoubleMerge
from scenarios.halting_car import HaltingCar
from scenarios.halting_car_braking import BrakingDistractorsHaltingCar
from scenarios.halting_car_reactive import ReactiveHaltingCar
from scenarios.left_turn import LeftTurn
from scenarios.roundabout_entry import RoundaboutEntry
from scenarios.versioning import Version, family_versions

DOUBLE_MERGE = family_versions(
    "double_merge",
    "Double Merge",
    Version(
        code=DoubleMerge,
        changes="first version: the rear car merges once it sees the front car settled",
        why="The paper's scenario; the front car ignores the rear one, so only one label is "
        "causal.",
    ),
    Version(
        code=ReactiveDoubleMerge,
        changes="both main cars react to each other: the rear car follows the front car "
        "(delayed IDM) once it sees it leave its lane, the front car paces the rear car's "
        "speed as seen 0.8 s earlier; hidden durations and delays fixed",
        why="Labels causal both ways, and what each main car is observed doing decides the "
        "other's future in the predicted window.",
    ),
)

HALTING_CAR = family_versions(
    "halting_car",
    "Halting Car",
    Version(
        code=HaltingCar,
        changes="first version: the leader may brake to a stop, the follower keeps its gap (IDM)",
        why="The paper's scenario; the leader brakes after the observed window, so nothing "
        "observed tells the follower's future.",
    ),
    Version(
        code=ReactiveHaltingCar,
        changes="braking onset inside the observed window (1.5-2.7 s); follower reaction "
        "delay of 0.6 or 0.9 s; headway 1.3-1.9 s",
        why="The leader's observed braking decides the follower's braking.",
    ),
    Version(
        settings={
            "brake_start_s": (2.4, 3.0),
            "reaction_delay_s": (0.9, 0.9),
            "stop_duration_s": (1.5, 1.5),
            "resume_accel_mps2": (2.5, 2.5),
        },
        changes="braking onset late in the observed window (2.4-3.0 s); reaction delay 0.9 s; "
        "stop (1.5 s) and resume (2.5 m/s^2) fixed",
        why="In v1 the follower often starts braking inside the observed window, so its own "
        "history shows much of its reaction; here only the leader's history shows the stop.",
    ),
    Version(
        settings={"cruise_speed_mps": (9.0, 11.0), "brake_decel_mps2": (4.0, 4.0)},
        changes="braking deceleration fixed at 4 m/s^2; cruising speed 9-11 m/s",
        why="The leader's observed braking then reads the same in every `stop` scene, so one "
        "linear reading of its history tells the case; the version to use for a new Halting "
        "Car study.",
    ),
    Version(
        code=BrakingDistractorsHaltingCar,
        changes="v3, with each outer lane's distractors braking together (to a lower speed or "
        "a stop) and resuming at random moments, never reacting to any car",
        why="With constant-speed distractors the mean over all cars is a scaled copy of the "
        "leader's braking, so averaging does the attention's job; here it cannot.",
    ),
)

LEFT_TURN = family_versions(
    "left_turn",
    "Unprotected Left Turn",
    Version(
        code=LeftTurn,
        changes="first version: a car turning left at an intersection waits for a gap in a "
        "stream of 3 oncoming cars; braking distractor columns",
        why="Attention that has to move: the turning car reads one oncoming car after another "
        "as each passes, and distractors brake and resume without any causal link.",
    ),
)

ROUNDABOUT_ENTRY = family_versions(
    "roundabout_entry",
    "Roundabout Entry",
    Version(
        code=RoundaboutEntry,
        changes="first version: a car entering a single-lane roundabout yields to a "
        "circulating car or goes ahead of it, which then follows it; braking distractor columns",
        why="What the entering car reads of the circulating car decides the case, labels are "
        "causal both ways, and distractors brake and resume without any causal link.",
    ),
    Version(
        settings={
            "arrival_timing": "decision",
            "entry_start_m": (29.0, 36.0),
            "yield_arrival_s": (-1.5, 1.5),
            "go_arrival_margin_s": (0.5, 1.5),
        },
        changes="the entering car starts 29-36 m before its line, so it decides after the "
        "observed window; the circulating car's arrival is timed from that decision (-1.5 to "
        "+1.5 s from it in `yield`, 0.5-1.5 s after the gap it needs in `go`)",
        why="In v0 the entering car goes inside the observed window in 80 % of `go` scenes, so "
        "its own history shows its choice and the circulating car's adds less (gain 47-61 %); "
        "the version to use for a new Roundabout Entry study.",
    ),
)

FAMILY_VERSIONS = (DOUBLE_MERGE, HALTING_CAR, LEFT_TURN, ROUNDABOUT_ENTRY)
