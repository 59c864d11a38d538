"""The user manual of a version's PettingZoo environment (its class docstring), written from
the version's configuration, its code's descriptions and the family's version history, as
Gymnasium's CartPole documents itself: description, action and observation spaces with units
and bounds, rewards, starting state, episode end, infos, arguments, version history.

Every number comes from the configuration, so a settings-only version's manual is right with no
text of its own; tests/test_envs.py checks the spaces, bounds and timing it states.
"""

from __future__ import annotations

import re
import textwrap

from scenarios.base import DISTRACTOR, Scenario, ScenarioConfig, span
from scenarios.frames import on_layout
from scenarios.junction import JunctionScenario
from scenarios.scenes import OTHER_FEATURES, observation_bounds
from scenarios.versioning import ScenarioVersion


def environment_manual(version: ScenarioVersion, history: list[ScenarioVersion]) -> str:
    """The manual of `version`'s environment; `history` is its family's versions up to it."""
    scenario = version.make()
    config = scenario.config
    sections = [
        f"{version.title} v{version.number} as a PettingZoo parallel environment ({version.name}).",
        _section("Description", _description(version, scenario)),
        _section("Action Space", _actions(config)),
        _section("Observation Space", _observations(scenario)),
        _section("Rewards", _rewards(scenario)),
        _section("Starting State", _starting_state(version, scenario)),
        _section("Episode End", _episode_end(version, config)),
        _section("Infos", _infos(version, config)),
        _section("Arguments", _arguments(version, config)),
        _section("Version History", _history(history)),
    ]
    return "\n\n".join(sections) + "\n"


def _section(title: str, body: str) -> str:
    return f"## {title}\n" + "\n".join(_wrap(line) for line in body.split("\n"))


def _wrap(line: str, width: int = 96) -> str:
    """A line of prose wrapped to `width`, never inside a `code span`; tables stay as they are
    and list items indent their continuation lines."""
    if line.startswith("|") or len(line) <= width:
        return line
    spans = re.split(r"(`[^`]*`)", line)
    glued = "".join(part.replace(" ", "\0") if part.startswith("`") else part for part in spans)
    indent = "  " if line.startswith("- ") else ""
    wrapped = textwrap.fill(
        glued, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False
    )
    return wrapped.replace("\0", " ")


def _description(version: ScenarioVersion, scenario: Scenario) -> str:
    config = scenario.config
    return (
        f"{version.scenario_class.manual_description(config)} {_distractors(scenario)} "
        f"All randomness comes from the reset seed; the ranges are the fields of "
        f"`{type(config).__name__}`, with this version's values from "
        f'`scenarios.version("{version.name}").config()` (the `config` argument takes one).'
    )


def _actions(config: ScenarioConfig) -> str:
    limits = config.limits
    low = [-limits.max_steer_rad, -limits.max_decel_mps2]
    high = [limits.max_steer_rad, limits.max_accel_mps2]
    return (
        f"`Box({low}, {high}, (2,), float32)` per agent: steering angle [rad] (positive turns "
        f"left) and acceleration [m/s^2]. An action is held for one env step = "
        f"{config.record_every} simulation steps of {config.dt_sim:g} s "
        f"({config.recorded_dt:g} s). Speeds stay in [0, {limits.max_speed_mps:g}] m/s.\n"
        "Values outside the bounds are clipped. `step` takes a dict with an action for exactly "
        "the live agents (`env.agents`); an action that is not 2 finite real numbers (a string, "
        "NaN, another shape) raises a ValueError naming the agent, before anything moves.\n"
        "`env.unwrapped.expert_actions()` gives the expert's action for every live agent, so "
        "you can drive some cars yourself and let the expert drive the rest."
    )


def _distractors(scenario: Scenario) -> str:
    """The sentence on the distractors: who they are and how they drive."""
    config = scenario.config
    indices = [index for index, role in enumerate(scenario.roles) if role == DISTRACTOR]
    if not indices:
        return "There are no distractors."
    cars = f"`car_{indices[0]}` ... `car_{indices[-1]}` are distractors"
    return f"{cars} {type(scenario).manual_distractors(config)}"


def _position_rows(scenario: Scenario) -> list[tuple[int, str]]:
    """The observation table's rows of the ego position and heading."""
    if on_layout(scenario):
        return [
            (0, "ego x [m] (world frame of the layout)"),
            (1, "ego y [m] (world frame of the layout)"),
            (2, "ego heading [rad] (0 = +x, counter-clockwise)"),
        ]
    return [
        (0, "ego x along the road [m]"),
        (1, f"ego y across the road [m] (lane i: {scenario.config.lane_width_m:g} i..)"),
        (2, "ego heading [rad] (0 = along the road)"),
    ]


def _observations(scenario: Scenario) -> str:
    num_cars = scenario.num_cars
    low, high = observation_bounds(scenario)
    rows = [
        *_position_rows(scenario),
        (3, "ego speed [m/s]"),
        (4, "other car k present (1) or removed (0)"),
        (5, "other car k: x - ego x [m]"),
        (6, "other car k: y - ego y [m]"),
        (7, "other car k: heading - ego heading [rad]"),
        (8, "other car k: speed - ego speed [m/s]"),
    ]
    table = [
        "| Index           | Observation                                   | Min    | Max   |",
        "|-----------------|-----------------------------------------------|--------|-------|",
    ]
    for index, text in rows:
        label = f"{index} + {OTHER_FEATURES}k" if index >= 4 else str(index)
        table.append(
            f"| {label:<15} | {text:<45} | {_bound(low[index]):<6} | {_bound(high[index]):<5} |"
        )
    size = len(low)
    return (
        f"`Box(float32, ({size},))` per agent: its own state, then for each other car in agent "
        "order (`car_0`, `car_1`, ..., skipping itself) a presence flag and its state relative "
        "to the ego car. Removed cars have presence 0 and zeros. Values are clipped to the "
        "bounds.\n\n" + "\n".join(table) + f"\n\nwith k = 0 ... {num_cars - 2} indexing the other "
        f"{num_cars - 1} cars."
    )


def _bound(value: float) -> str:
    """A bound as the table writes it: pi by name, integers without a decimal point."""
    for multiple, text in ((1.0, "pi"), (-1.0, "-pi")):
        if abs(value - multiple * 3.141592653589793) < 1e-6:
            return text
    return f"{value:g}"


def _rewards(scenario: Scenario) -> str:
    top = scenario.config.limits.max_speed_mps
    if on_layout(scenario):
        progress = (
            f"`speed_reward_weight * v cos(heading - route heading) / {top:g}` (progress along "
            "the car's own route, its heading relative to the route's at the car's closest "
            "point on it; at most 0.1 by default)"
        )
    else:
        progress = (
            f"`speed_reward_weight * v cos(heading) / {top:g}` (forward progress, at most 0.1 by "
            "default)"
        )
    return (
        f"Per agent and step: {progress}, plus `collision_reward` (-1) if it collided and "
        "`off_road_reward` (-1) if any part of it left the road during the step."
    )


def _starting_state(version: ScenarioVersion, scenario: Scenario) -> str:
    config = scenario.config
    if isinstance(scenario, JunctionScenario):
        return (
            f"{version.scenario_class.manual_starting_state(config)} Distractor columns: "
            f"{config.platoon_size} cars {span(config.distractor_gap_m, 'm')} apart (centre to "
            "centre)."
        )
    per_lane = config.num_distractors - config.num_distractors // 2
    first = span(config.distractor_first_x_m).replace(" to ", ", ")
    return (
        f"{version.scenario_class.manual_starting_state(config)} Distractors: {per_lane} per "
        f"outer lane, {span(config.distractor_gap_m, 'm')} apart, the rearmost at x in "
        f"[{first}] m."
    )


def _episode_end(version: ScenarioVersion, config: ScenarioConfig) -> str:
    note = version.scenario_class.manual_split_note(config)
    return (
        f"- Termination (per agent): it collided with another car or left the road (checked "
        f"every {config.dt_sim:g} s). The car is then removed from the world and from `agents` "
        "for good.\n"
        f"- Truncation (all agents): after `max_cycles` steps (default {config.num_steps} = "
        f"{config.duration_s:g} s, the scenario's episode length; suggested split for "
        f"prediction: {config.num_observed} observed + {config.num_predicted} predicted steps"
        f"{', ' + note if note else ''})."
    )


def _infos(version: ScenarioVersion, config: ScenarioConfig) -> str:
    return (
        'Each agent\'s info: `role` ("main_green", "main_brown" or "distractor"), `attention` '
        "(index of the car it reacts to, -1 for none), `interaction` (the scene is in its "
        "interaction period), `collided`, `off_road`. Labels: "
        f"{version.scenario_class.manual_labels(config)}."
    )


def _arguments(version: ScenarioVersion, config: ScenarioConfig) -> str:
    code = version.scenario_class
    rows = [
        ("`case`", "str", f'"{code.default_major_case}"', "case when reset gets no option"),
        ("`max_cycles`", "int", str(config.num_steps), "steps before truncation"),
        ("`render_mode`", "str", "None", '"rgb_array" or "human"'),
        ("`config`", type(config).__name__, "this version's", "timings, ranges, road, limits"),
        ("`speed_reward_weight`", "float", "0.1", "weight of the progress reward"),
        ("`collision_reward`", "float", "-1.0", "reward on collision"),
        ("`off_road_reward`", "float", "-1.0", "reward on leaving the road"),
    ]
    table = ["| Parameter | Type | Default | Description |", "|---|---|---|---|"]
    table += [f"| {' | '.join(row)} |" for row in rows]
    other = next(case for case in code.case_names if case != code.default_major_case)
    return (
        "\n".join(table)
        + f'\n\n`reset(seed=..., options={{"case": "{other}"}})` picks the case of one episode '
        '("case" is the only option; any other key is ignored with a UserWarning). With a '
        "seed, stepping every agent with `expert_actions()` reproduces "
        f'`scenarios.rollout(scenarios.make("{version.name}"), seed, case)` exactly; without '
        "one, `env.unwrapped.episode_seed` says which seed was used. "
        f"`scenarios.{version.name}.vector_env(num_envs)` steps many scenes at once."
    )


def _history(history: list[ScenarioVersion]) -> str:
    return "\n".join(f"- v{version.number}: {version.changes}." for version in reversed(history))
