"""The road a viewer page draws, from a dataset's recorded scenario: the straight road's
dimensions, or a junction layout's lanes as polygons.

A junction scenario (`scenarios.junction.JunctionScenario`) is rebuilt from the dataset's
version name and stored configuration, and every lane of its layout becomes one polygon: the
centre-line offset by half the lane width to the left (start to end) and then to the right (end
to start), straight pieces by their ends and arcs every `ARC_STEP_M`. The page fills the
polygons; their union is the road surface, as the simulator's off-road check has it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from carlo_lite import Lane, Segment
from scenarios import stored_version
from scenarios.junction import JunctionScenario
from scenarios.versioning import ScenarioVersion
from trajectory_data.format import DatasetMeta

ROAD_KEYS = ("num_lanes", "lane_width_m", "road_length_m", "car_length_m", "car_width_m")
CAR_KEYS = ("car_length_m", "car_width_m")
ARC_STEP_M = 0.5  # centre-line spacing of the polygon's points along an arc [m]
DECIMALS = 2  # polygon coordinates are rounded to cm


def road_of(meta: DatasetMeta) -> dict | None:
    """The road of a synthetic scenario, None for real data (no road recorded): the page then
    draws agents as dots on a plain background.

    Straight road: {num_lanes, lane_width_m, road_length_m, car_length_m, car_width_m}.
    Junction: {car_length_m, car_width_m, lanes: [[x0, y0, x1, y1, ...], ...]}, one flat polygon
    per lane of the layout [m]."""
    stored = meta.config.get("scenario")
    if not isinstance(stored, dict) or any(k not in stored for k in CAR_KEYS):
        return None
    version = _version(meta.scenario)
    if version is not None and issubclass(version.scenario_class, JunctionScenario):
        scenario = version.make(stored_config(version, stored))
        lanes = [lane_polygon(lane) for lane in scenario.layout.lanes.values()]
        return {**{key: float(stored[key]) for key in CAR_KEYS}, "lanes": lanes}
    if any(k not in stored for k in ROAD_KEYS):
        return None
    return {key: float(stored[key]) for key in ROAD_KEYS}


def _version(name: Any) -> ScenarioVersion | None:
    """The registered version a dataset records, None for a name the registry does not know
    (real data, a version of a newer checkout)."""
    try:
        return stored_version(str(name))
    except ValueError:
        return None


def stored_config(version: ScenarioVersion, stored: dict):
    """The scenario configuration a dataset stored (`ScenarioConfig.to_dict`): its plain fields
    (lists back to ranges) over the version's settings; nested settings (limits, gains) keep
    the version's, which the road does not depend on. The version's own configuration when the
    stored values do not make a valid one."""
    fields = {field.name for field in dataclasses.fields(version.scenario_class.config_class)}
    values = {
        name: tuple(value) if isinstance(value, list) else value
        for name, value in stored.items()
        if name in fields and not isinstance(value, dict)
    }
    try:
        return version.config(**values)
    except (TypeError, ValueError):
        return version.config()


def lane_polygon(lane: Lane) -> list[float]:
    """The outline of `lane` as a flat [x0, y0, x1, y1, ...] list [m]: its left edge from start
    to end, then its right edge back."""
    s = _outline_stations(lane)
    half = 0.5 * lane.width_m
    left, right = lane.position(s, half), lane.position(s, -half)  # (K, 2) each
    outline = np.concatenate([left, right[::-1]])
    return np.round(outline, DECIMALS).reshape(-1).tolist()


def _outline_stations(lane: Lane) -> np.ndarray:
    """Arc lengths (K,) along `lane` where its outline needs a point: both ends of each straight
    piece and every `ARC_STEP_M` along each arc."""
    stations, start = [], 0.0
    for piece in lane.pieces:
        length = piece.length_m
        count = 2 if isinstance(piece, Segment) else max(2, int(np.ceil(length / ARC_STEP_M)) + 1)
        stations.append(start + np.linspace(0.0, length, count))
        start += length
    return np.unique(np.concatenate(stations))  # a piece's end is the next one's start
