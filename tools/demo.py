"""The README's main job on a built-in default: a short simulator demo that writes pictures.

Drives 22 cars on a 4-lane road for 8 s (one of them changes lane with a hand-made steering
profile), checks collisions and off-road every step, and writes a top-down frame and a GIF.
Usage: python tools/demo.py [--out outputs/demo]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from carlo_lite import StraightRoad, World, render_rgb  # noqa: E402


def demo_world(seed: int = 0) -> World:
    """Two main cars in the inner lanes and 20 distractors on the outer lanes."""
    rng = np.random.default_rng(seed)
    road = StraightRoad(num_lanes=4, length_m=400.0)
    main_xy = [[60.0, road.lane_center_y(1)], [70.0, road.lane_center_y(2)]]
    outer_lanes = np.tile([0, 3], 10)
    distractor_x = np.repeat(np.arange(10) * 14.0, 2) + rng.uniform(0, 4, 20)
    distractor_y = [road.lane_center_y(int(lane)) for lane in outer_lanes]
    xy = np.vstack([main_xy, np.column_stack([distractor_x, distractor_y])])
    speed = np.concatenate([[12.0, 12.0], np.full(20, 12.0)])
    roles = ["main_green", "main_brown"] + ["distractor"] * 20
    return World(road, xy, np.zeros(22), speed, roles=roles)


def lane_change_steering(step: int) -> float:
    """An S-shaped steering profile [rad] that moves a car one lane to the left at 12 m/s."""
    if 10 <= step < 20:
        return 0.04
    if 20 <= step < 30:
        return -0.04
    return 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description="carlo_lite demo: writes a frame and a GIF")
    parser.add_argument(
        "--out", default="outputs/demo", help="output folder (default outputs/demo)"
    )
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    world = demo_world()
    frames = []
    incidents = 0
    for step in range(80):
        controls = np.zeros((world.num_cars, 2))
        controls[0, 0] = lane_change_steering(step)
        world.step(controls)
        incidents += int(world.collisions().sum() + world.off_road().sum())
        if step % 2 == 0:
            frames.append(render_rgb(world, 640, 160, center_xy=(float(world.xy[0, 0]), 7.0)))
    iio.imwrite(out / "simulator.png", frames[-1])
    iio.imwrite(out / "simulator.gif", np.stack(frames), duration=200, loop=0)
    seconds = time.perf_counter() - start
    print(
        f"demo: 80 steps of 22 cars, {incidents} collision/off-road events, {seconds:.1f} s; "
        f"wrote {out / 'simulator.png'} and {out / 'simulator.gif'}"
    )


if __name__ == "__main__":
    main()
