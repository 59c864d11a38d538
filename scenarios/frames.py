"""The environments' top-down frames of one scene: what part of the world they show.

- Straight road: a wide strip (800 x 200 px) that fits the road's width and follows the main
  cars along it (centred on the mean x of the active ones among `car_0` and `car_1`).
- Junction (a scenario on a `carlo_lite.RoadLayout`): a fixed square (400 x 400 px) centred on
  the junction (the middle of the scenario's `position_bounds()`), showing
  `JUNCTION_HALF_SPAN_M` either side of it; cars further out enter the frame as they approach.
"""

from __future__ import annotations

import numpy as np

from carlo_lite import RoadLayout, World, render_rgb
from scenarios.base import Scenario

FRAME_WIDTH_PX, FRAME_HEIGHT_PX = 800, 200  # straight road
JUNCTION_FRAME_PX = 400  # width and height of a junction frame
JUNCTION_HALF_SPAN_M = 60.0  # a junction frame shows this much either side of its centre [m]


def on_layout(scenario: Scenario) -> bool:
    """The scenario drives on a road layout (a junction), not on the straight road."""
    return isinstance(scenario.road, RoadLayout)


def frame_size(scenario: Scenario) -> tuple[int, int]:
    """(width, height) [px] of the environments' frames of `scenario`."""
    if on_layout(scenario):
        return JUNCTION_FRAME_PX, JUNCTION_FRAME_PX
    return FRAME_WIDTH_PX, FRAME_HEIGHT_PX


def render_scene(
    scenario: Scenario, world: World, width_px: int | None = None, height_px: int | None = None
) -> np.ndarray:
    """A (height, width, 3) uint8 top-down frame of `world`, one scene of `scenario`, framed as
    the module docstring says (default size: `frame_size`)."""
    default_width, default_height = frame_size(scenario)
    width_px = default_width if width_px is None else width_px
    height_px = default_height if height_px is None else height_px
    if on_layout(scenario):
        x_min, y_min, x_max, y_max = scenario.position_bounds()
        center = (0.5 * (x_min + x_max), 0.5 * (y_min + y_max))
        scale = 2.0 * JUNCTION_HALF_SPAN_M / min(width_px, height_px)
        return render_rgb(world, width_px, height_px, center_xy=center, metres_per_px=scale)
    main = np.nonzero(world.active[:2])[0]
    center = None
    if len(main):
        center = (float(world.xy[main, 0].mean()), 0.5 * scenario.road.width_m)
    return render_rgb(world, width_px, height_px, center_xy=center)
