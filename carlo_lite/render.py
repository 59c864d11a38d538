"""Top-down rendering: `render_rgb` draws a frame with numpy alone (no display needed);
`HumanViewer` shows frames in a pygame window (pygame imported lazily, `render` extra)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from carlo_lite.layouts import RoadLayout
from carlo_lite.world import World

# Colours (RGB) by role; the paper draws the two main cars green and brown, the others white.
ROLE_COLORS: dict[str, tuple[int, int, int]] = {
    "main_green": (46, 160, 67),
    "main_brown": (150, 95, 45),
    "distractor": (240, 240, 240),
}
DEFAULT_CAR_COLOR = (200, 200, 200)
GRASS_COLOR = (96, 128, 80)
ROAD_COLOR = (70, 70, 74)
MARKING_COLOR = (235, 235, 235)
OUTLINE_COLOR = (20, 20, 20)


@dataclass(frozen=True)
class View:
    """The world rectangle shown in a frame: centre [m] and scale [m per pixel]."""

    center_xy: tuple[float, float]
    metres_per_px: float
    width_px: int
    height_px: int

    def pixel_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """World x (W,) and y (H,) of pixel centres; row 0 is the top (largest y)."""
        cols = (np.arange(self.width_px) + 0.5 - self.width_px / 2) * self.metres_per_px
        rows = (self.height_px / 2 - np.arange(self.height_px) - 0.5) * self.metres_per_px
        return self.center_xy[0] + cols, self.center_xy[1] + rows

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Fractional (col, row) pixel coordinates of world points (..., 2)."""
        col = (xy[..., 0] - self.center_xy[0]) / self.metres_per_px + self.width_px / 2
        row = self.height_px / 2 - (xy[..., 1] - self.center_xy[1]) / self.metres_per_px
        return np.stack([col, row], axis=-1)


def default_view(world: World, width_px: int, height_px: int) -> View:
    """Straight road: fit its width (plus a margin) in the frame height, centred on the active
    cars. Road layout: fit the whole layout in the frame."""
    if isinstance(world.road, RoadLayout):
        return layout_view(world.road, width_px, height_px)
    metres_per_px = (world.road.width_m + 6.0) / height_px
    active_x = world.xy[world.active, 0]
    center_x = float(active_x.mean()) if len(active_x) else world.road.length_m / 2
    return View((center_x, world.road.width_m / 2), metres_per_px, width_px, height_px)


def layout_view(layout: RoadLayout, width_px: int, height_px: int) -> View:
    """The view that fits all of `layout` (plus 2 m) in the frame."""
    x_min, y_min, x_max, y_max = layout.bounds(margin_m=2.0)
    metres_per_px = max((x_max - x_min) / width_px, (y_max - y_min) / height_px)
    center = ((x_min + x_max) / 2, (y_min + y_max) / 2)
    return View(center, metres_per_px, width_px, height_px)


def _chosen(
    fitted: View, center_xy: tuple[float, float] | None, metres_per_px: float | None
) -> View:
    """`fitted` with the caller's centre and scale where given."""
    return View(
        center_xy if center_xy is not None else fitted.center_xy,
        metres_per_px if metres_per_px is not None else fitted.metres_per_px,
        fitted.width_px,
        fitted.height_px,
    )


def _fill_band(
    frame: np.ndarray, ys: np.ndarray, low: float, high: float, color, mask_x=None
) -> None:
    rows = (ys >= low) & (ys <= high)
    if mask_x is None:
        frame[rows, :] = color
    else:
        frame[np.ix_(rows, mask_x)] = color


def _draw_road(frame: np.ndarray, world: World, view: View) -> None:
    if isinstance(world.road, RoadLayout):
        _draw_layout(frame, world.road, view)
        return
    xs, ys = view.pixel_centres()
    road = world.road
    on_road_x = (xs >= 0) & (xs <= road.length_m)
    _fill_band(frame, ys, 0.0, road.width_m, ROAD_COLOR, on_road_x)
    line_half = max(0.08, 0.6 * view.metres_per_px)  # markings at least ~1 px wide
    for edge_y in road.lateral_bounds:
        _fill_band(frame, ys, edge_y - line_half, edge_y + line_half, MARKING_COLOR, on_road_x)
    dashes = on_road_x & (np.mod(xs, 9.0) < 3.0)  # 3 m dashes every 9 m
    for marking_y in road.marking_lines_y():
        _fill_band(frame, ys, marking_y - line_half, marking_y + line_half, MARKING_COLOR, dashes)


def _draw_layout(frame: np.ndarray, layout: RoadLayout, view: View) -> None:
    """Road pixels are those whose centre lies on some lane; road pixels next to an off-road
    pixel are the edge line."""
    xs, ys = view.pixel_centres()
    grid = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None]), axis=-1)  # (H, W, 2)
    road = layout.on_road(grid)
    padded = np.pad(road, 1, mode="edge")
    edge = road & ~(padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:])
    frame[road] = ROAD_COLOR
    frame[edge] = MARKING_COLOR


def _draw_box(frame, view, xs, ys, center, heading, length, width, color) -> None:
    reach = 0.5 * np.hypot(length, width)
    cols = np.nonzero(np.abs(xs - center[0]) <= reach)[0]
    rows = np.nonzero(np.abs(ys - center[1]) <= reach)[0]
    if len(cols) == 0 or len(rows) == 0:
        return
    dx = xs[cols][None, :] - center[0]  # (h, w)
    dy = ys[rows][:, None] - center[1]
    along = dx * np.cos(heading) + dy * np.sin(heading)
    across = -dx * np.sin(heading) + dy * np.cos(heading)
    inside = (np.abs(along) <= length / 2) & (np.abs(across) <= width / 2)
    block = frame[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    block[inside] = color


def render_rgb(
    world: World,
    width_px: int = 800,
    height_px: int = 200,
    center_xy: tuple[float, float] | None = None,
    metres_per_px: float | None = None,
) -> np.ndarray:
    """A top-down picture (height_px, width_px, 3) uint8 of the road and the active cars.

    By default the view fits the road's width and is centred on the mean position of the
    active cars; pass `center_xy` and/or `metres_per_px` to choose it.
    """
    if width_px < 1 or height_px < 1:
        raise ValueError("frame size must be at least 1 x 1 pixel")
    view = _chosen(default_view(world, width_px, height_px), center_xy, metres_per_px)
    frame = np.full((height_px, width_px, 3), GRASS_COLOR, dtype=np.uint8)
    _draw_road(frame, world, view)
    _draw_cars(frame, world, view)
    return frame


def _draw_cars(frame: np.ndarray, world: World, view: View) -> None:
    xs, ys = view.pixel_centres()
    outline = 2.0 * view.metres_per_px
    for car in np.nonzero(world.active)[0]:
        center, heading = world.xy[car], world.heading[car]
        length, width = world.length_m[car], world.width_m[car]
        color = ROLE_COLORS.get(world.roles[car], DEFAULT_CAR_COLOR)
        _draw_box(frame, view, xs, ys, center, heading, length, width, OUTLINE_COLOR)
        _draw_box(frame, view, xs, ys, center, heading, length - outline, width - outline, color)


def render_layout(
    layout: RoadLayout,
    width_px: int = 600,
    height_px: int = 600,
    center_xy: tuple[float, float] | None = None,
    metres_per_px: float | None = None,
    world: World | None = None,
) -> np.ndarray:
    """A top-down picture (height_px, width_px, 3) uint8 of any `RoadLayout` (intersection,
    roundabout, `StraightRoad.layout()`), and of the active cars of `world` if given.

    Road pixels are those whose centre lies on some lane; road pixels next to an off-road pixel
    are drawn as the edge line. By default the view fits the whole layout.
    """
    if width_px < 1 or height_px < 1:
        raise ValueError("frame size must be at least 1 x 1 pixel")
    view = _chosen(layout_view(layout, width_px, height_px), center_xy, metres_per_px)
    frame = np.full((height_px, width_px, 3), GRASS_COLOR, dtype=np.uint8)
    _draw_layout(frame, layout, view)
    if world is not None:
        _draw_cars(frame, world, view)
    return frame


class HumanViewer:
    """A pygame window that shows rgb frames; needs the `render` extra (pygame) and a display."""

    def __init__(self, caption: str = "carlo_lite", fps: float = 10.0) -> None:
        self.caption = caption
        self.fps = fps
        self._screen = None
        self._clock = None

    def show(self, frame: np.ndarray) -> None:
        """Display `frame` (H, W, 3) uint8, opening the window on first use."""
        # pygame greets on stdout at its first import, which would mix into a tool's output
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        try:
            import pygame
        except ImportError as error:  # pragma: no cover - depends on the optional extra
            raise ImportError(
                "human rendering needs pygame: pip install 'smooth-attention[render]'"
            ) from error
        if self._screen is None:
            pygame.init()
            pygame.display.set_caption(self.caption)
            self._screen = pygame.display.set_mode((frame.shape[1], frame.shape[0]))
            self._clock = pygame.time.Clock()
        pygame.event.pump()
        surface = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self._screen.blit(surface, (0, 0))
        pygame.display.flip()
        self._clock.tick(self.fps)

    def close(self) -> None:
        if self._screen is not None:
            import pygame

            pygame.display.quit()
            pygame.quit()
            self._screen = None
