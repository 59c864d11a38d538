"""carlo_lite: a small, fast, headless 2-D driving simulator in the spirit of CARLO.

Kinematic bicycle cars on multi-lane roads, stepped together with numpy; collision and off-road
checks with pymunk; top-down rendering with numpy (pygame only for a window). SI units,
`dt = 0.1 s` by default. This package knows nothing of scenarios or learning.
"""

from carlo_lite.batched import BatchedWorld
from carlo_lite.kinematics import CarLimits, bicycle_step, box_corners, wrap_angle
from carlo_lite.render import ROLE_COLORS, HumanViewer, render_rgb
from carlo_lite.road import StraightLane, StraightRoad
from carlo_lite.world import World

__all__ = [
    "BatchedWorld",
    "CarLimits",
    "HumanViewer",
    "ROLE_COLORS",
    "StraightLane",
    "StraightRoad",
    "World",
    "bicycle_step",
    "box_corners",
    "render_rgb",
    "wrap_angle",
]
