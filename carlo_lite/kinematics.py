"""Kinematic bicycle model, stepped for all cars at once (structure of arrays, no loop over cars).

Model (rear-axle reference, applied at the car's centre, which is also the centre of its body
rectangle):

    x' = v cos(psi),   y' = v sin(psi),   psi' = v tan(delta) / wheelbase,   v' = a

With steering delta and acceleration a held constant over a step, the path is an arc of constant
curvature kappa = tan(delta) / wheelbase whatever the speed profile, so the step is integrated
exactly: the arc length follows from the (clipped) speed profile and the pose from the arc.
A constant steering angle therefore traces a circle of radius wheelbase / tan(delta).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CarLimits:
    """Control and speed limits shared by all cars; controls outside them are clipped."""

    max_steer_rad: float = 0.5  # |steering angle| [rad] (about 29 degrees)
    max_accel_mps2: float = 4.0  # strongest forward acceleration [m/s^2]
    max_decel_mps2: float = 8.0  # strongest braking [m/s^2] (about 0.8 g)
    max_speed_mps: float = 40.0  # speed is kept in [0, max_speed_mps] [m/s]

    def clip_controls(self, controls: np.ndarray) -> np.ndarray:
        """Clip (N, 2) [steering rad, acceleration m/s^2] controls to the limits (new array)."""
        clipped = np.empty_like(controls, dtype=float)
        np.clip(controls[:, 0], -self.max_steer_rad, self.max_steer_rad, out=clipped[:, 0])
        np.clip(controls[:, 1], -self.max_decel_mps2, self.max_accel_mps2, out=clipped[:, 1])
        return clipped


def arc_length(
    speed: np.ndarray, accel: np.ndarray, dt: float, max_speed: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distance travelled [m] and final speed [m/s] over `dt` under constant acceleration.

    The speed is held in [0, max_speed]: a braking car stops and stays stopped, an accelerating
    car cruises once it reaches `max_speed`.
    """
    free_speed = speed + accel * dt  # final speed if no limit is reached
    final_speed = np.clip(free_speed, 0.0, max_speed)
    distance = 0.5 * dt * (speed + free_speed)  # exact while no limit is reached
    limited = final_speed != free_speed
    if limited.any():  # ramp to the limit, then hold it for the rest of the step
        v0, a, v1 = speed[limited], accel[limited], final_speed[limited]
        ramp_time = (v1 - v0) / a
        distance[limited] = 0.5 * ramp_time * (v0 + v1) + v1 * (dt - ramp_time)
    return distance, final_speed


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles [rad] to [-pi, pi): exactly `(angle + pi) % (2 pi) - pi`, a new array.

    numpy's float modulo is slow (about 4x the rest of this function), so angles in (-3 pi,
    3 pi), all that a step or a difference of two wrapped angles produces, take a shortcut: for
    s = angle + pi in (-2 pi, 4 pi) the modulo is s, s - 2 pi (exact, Sterbenz) or s + 2 pi
    (rounded as numpy rounds it); tests hold the two equal bit for bit.
    """
    shifted = np.asarray(angle, dtype=float) + np.pi
    if shifted.size < 2 or not (shifted.min() > -2.0 * np.pi and shifted.max() < 4.0 * np.pi):
        return shifted % (2.0 * np.pi) - np.pi  # a scalar, an empty array, or far out
    np.subtract(shifted, 2.0 * np.pi, out=shifted, where=shifted >= 2.0 * np.pi)
    np.add(shifted, 2.0 * np.pi, out=shifted, where=shifted < 0.0)  # none of the above
    shifted -= np.pi
    return shifted


def bicycle_step(
    xy: np.ndarray,
    heading: np.ndarray,
    speed: np.ndarray,
    controls: np.ndarray,
    wheelbase: np.ndarray,
    dt: float,
    max_speed: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance all cars one step; returns new (xy (N, 2), heading (N,), speed (N,)).

    `controls` (N, 2) must already be finite and clipped; integration is exact (see module doc).
    """
    distance, new_speed = arc_length(speed, controls[:, 1], dt, max_speed)
    curvature = np.tan(controls[:, 0]) / wheelbase  # (N,) [1/m]
    turn = curvature * distance  # (N,) heading change [rad]
    # Chord of the arc: length distance * sin(turn/2)/(turn/2), direction heading + turn/2.
    half_turn = 0.5 * turn
    shrink = np.divide(np.sin(half_turn), half_turn, out=np.ones_like(turn), where=turn != 0.0)
    chord = distance * shrink
    mid_heading = heading + half_turn
    new_xy = np.empty_like(xy)
    new_xy[:, 0] = xy[:, 0] + chord * np.cos(mid_heading)
    new_xy[:, 1] = xy[:, 1] + chord * np.sin(mid_heading)
    return new_xy, wrap_angle(heading + turn), new_speed


def box_corners(
    xy: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """Corners (N, 4, 2) of rectangles centred at `xy`, counter-clockwise from front-left."""
    cos, sin = np.cos(heading), np.sin(heading)
    half_l, half_w = 0.5 * length, 0.5 * width
    local = np.stack(
        [
            np.stack([half_l, half_w], axis=-1),
            np.stack([-half_l, half_w], axis=-1),
            np.stack([-half_l, -half_w], axis=-1),
            np.stack([half_l, -half_w], axis=-1),
        ],
        axis=1,
    )  # (N, 4, 2)
    corners = np.empty_like(local)
    corners[..., 0] = xy[:, None, 0] + local[..., 0] * cos[:, None] - local[..., 1] * sin[:, None]
    corners[..., 1] = xy[:, None, 1] + local[..., 0] * sin[:, None] + local[..., 1] * cos[:, None]
    return corners
