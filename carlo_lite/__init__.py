"""carlo_lite: a small, fast, headless 2-D driving simulator in the spirit of CARLO.

Kinematic bicycle cars on multi-lane roads (lanes of segments and arcs, intersections and
roundabouts in `lanes` / `layouts`), stepped together with numpy; collision and off-road
checks with pymunk; top-down rendering with numpy (pygame only for a window). SI units,
`dt = 0.1 s` by default. This package knows nothing of scenarios or learning.
"""

from carlo_lite.batched import BatchedWorld
from carlo_lite.kinematics import CarLimits, bicycle_step, box_corners, wrap_angle
from carlo_lite.lanes import Arc, Lane, LanePath, Segment, join_lanes
from carlo_lite.layouts import Intersection, RoadLayout, Roundabout
from carlo_lite.render import ROLE_COLORS, HumanViewer, render_layout, render_rgb
from carlo_lite.road import StraightLane, StraightRoad
from carlo_lite.world import World

__all__ = [
    "Arc",
    "BatchedWorld",
    "CarLimits",
    "HumanViewer",
    "Intersection",
    "Lane",
    "LanePath",
    "ROLE_COLORS",
    "RoadLayout",
    "Roundabout",
    "Segment",
    "StraightLane",
    "StraightRoad",
    "World",
    "bicycle_step",
    "box_corners",
    "join_lanes",
    "render_layout",
    "render_rgb",
    "wrap_angle",
]
