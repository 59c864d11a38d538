"""Small reusable driving controllers, vectorised over cars (pure numpy, no simulator needed).

Both scenarios build their expert policies from these four pieces:

- `lane_change_reference`: a smooth (quintic, minimum-jerk) lateral reference from one offset to
  another, with its rate as feed-forward;
- `lateral_steering`: steering that tracks a lateral reference (lane keeping is the special
  case of a constant reference at the lane centre);
- `speed_tracking_accel`: proportional speed control with acceleration limits;
- `idm_accel`: the Intelligent Driver Model (Treiber, Hennecke, Helbing 2000) for car following.

Every function takes arrays of shape (N,) (or scalars) and returns (N,) arrays. Coordinates are
in a lane-aligned frame: `lateral_m` is the lateral position [m] (positive to the left) and
`heading_rad` the heading relative to the lane direction [rad]. Controls are held constant for
one control period (zero-order hold), so the gains below are chosen for periods up to ~0.3 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carlo_lite.kinematics import wrap_angle


@dataclass(frozen=True)
class LateralGains:
    """Gains of the lateral tracking law (see `lateral_steering`).

    The tracking error for small angles obeys e'' + k_h e' + k_h k_p e = 0, a
    second-order system with natural frequency sqrt(k_h k_p) and damping k_h / (2 sqrt(k_h k_p));
    the defaults give 1.41 rad/s and 0.88 (well damped, no visible overshoot).
    """

    position_gain_per_s: float = 0.8  # k_p: lateral error [m] -> lateral velocity [m/s]
    heading_gain_per_s: float = 2.5  # k_h: heading error [rad] -> yaw rate [rad/s]
    max_heading_rad: float = 0.35  # largest heading the law asks for, relative to the lane
    min_speed_mps: float = 1.0  # speeds below this are treated as this (avoids dividing by 0)

    def __post_init__(self) -> None:
        if min(self.position_gain_per_s, self.heading_gain_per_s, self.min_speed_mps) <= 0:
            raise ValueError("LateralGains: gains and min_speed_mps must be positive")
        if not 0 < self.max_heading_rad < np.pi / 2:
            raise ValueError("LateralGains: max_heading_rad must be in (0, pi/2)")


@dataclass(frozen=True)
class IDMParams:
    """Intelligent Driver Model parameters (desired speed is given per car at call time)."""

    time_headway_s: float = 1.5  # T: desired time gap to the leader [s]
    min_gap_m: float = 2.0  # s0: bumper-to-bumper gap kept when standing [m]
    max_accel_mps2: float = 2.0  # a: largest acceleration [m/s^2]
    comfortable_decel_mps2: float = 3.0  # b: comfortable braking [m/s^2]
    exponent: float = 4.0  # delta: how the free-road term falls off near the desired speed
    max_decel_mps2: float = 8.0  # hard limit on braking [m/s^2] (the car's physical limit)

    def __post_init__(self) -> None:
        values = (
            self.time_headway_s,
            self.min_gap_m,
            self.max_accel_mps2,
            self.comfortable_decel_mps2,
            self.exponent,
            self.max_decel_mps2,
        )
        if min(values) <= 0:
            raise ValueError("IDMParams: every parameter must be positive")


def quintic_blend(progress: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 with its first two derivatives.

    tau is clipped to [0, 1]; s goes from 0 to 1 with zero slope and curvature at both ends.
    Returns (s, ds/dtau, d2s/dtau2).
    """
    tau = np.clip(np.asarray(progress, dtype=float), 0.0, 1.0)
    value = tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau))
    slope = 30.0 * tau**2 * (1.0 - tau) ** 2
    curvature = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return value, slope, curvature


def lane_change_reference(
    time_s: np.ndarray | float,
    start_s: np.ndarray | float,
    duration_s: np.ndarray | float,
    from_m: np.ndarray | float,
    to_m: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lateral reference [m], rate [m/s] and acceleration [m/s^2] of a smooth lateral move.

    The move from `from_m` to `to_m` starts at `start_s` and lasts `duration_s` [s]; before it
    the reference is `from_m`, after it `to_m`. Peak lateral speed 1.875 |shift| / duration,
    peak lateral acceleration 5.7735 |shift| / duration^2.
    """
    duration = np.asarray(duration_s, dtype=float)
    if np.any(duration <= 0):
        raise ValueError("lane change duration must be positive")
    shift = np.asarray(to_m, dtype=float) - np.asarray(from_m, dtype=float)
    value, slope, curvature = quintic_blend((np.asarray(time_s, dtype=float) - start_s) / duration)
    return from_m + shift * value, shift * slope / duration, shift * curvature / duration**2


def lateral_steering(
    lateral_m: np.ndarray,
    heading_rad: np.ndarray,
    speed_mps: np.ndarray,
    target_lateral_m: np.ndarray | float,
    target_rate_mps: np.ndarray | float,
    wheelbase_m: np.ndarray | float,
    gains: LateralGains = LateralGains(),
    target_accel_mps2: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Steering [rad] that makes the lateral position track a reference.

    Cascade: the lateral error sets a desired lateral velocity (plus the reference rate as
    feed-forward), hence a desired heading; the heading error sets a desired yaw rate (plus the
    reference's lateral acceleration / speed as feed-forward), and the kinematic bicycle
    relation yaw_rate = v tan(delta) / wheelbase gives the steering angle. With both
    feed-forwards the tracking error obeys e'' + k_h e' + k_h k_p e = 0 (small angles).
    """
    speed = np.maximum(np.asarray(speed_mps, dtype=float), gains.min_speed_mps)
    lateral_velocity = target_rate_mps + gains.position_gain_per_s * (target_lateral_m - lateral_m)
    max_sine = np.sin(gains.max_heading_rad)
    desired_heading = np.arcsin(np.clip(lateral_velocity / speed, -max_sine, max_sine))
    heading_error = wrap_angle(desired_heading - heading_rad)  # [-pi, pi)
    yaw_rate = gains.heading_gain_per_s * heading_error + target_accel_mps2 / speed
    return np.arctan(yaw_rate * wheelbase_m / speed)


def speed_tracking_accel(
    speed_mps: np.ndarray,
    target_speed_mps: np.ndarray | float,
    gain_per_s: float,
    max_accel_mps2: float,
    max_decel_mps2: float,
) -> np.ndarray:
    """Acceleration [m/s^2] = gain * (target - speed), clipped to [-max_decel, max_accel]."""
    accel = gain_per_s * (np.asarray(target_speed_mps, dtype=float) - speed_mps)
    return np.clip(accel, -max_decel_mps2, max_accel_mps2)


def idm_accel(
    speed_mps: np.ndarray,
    desired_speed_mps: np.ndarray | float,
    gap_m: np.ndarray,
    approach_rate_mps: np.ndarray,
    params: IDMParams = IDMParams(),
) -> np.ndarray:
    """IDM acceleration [m/s^2] of a follower, clipped to [-max_decel, max_accel].

    `gap_m` is the bumper-to-bumper distance to the leader (use `np.inf` for a free road) and
    `approach_rate_mps` = follower speed - leader speed (positive when closing in).
    a = a_max [1 - (v / v0)^delta - (s* / s)^2],  s* = s0 + max(0, v T + v dv / (2 sqrt(a b))).
    """
    speed = np.asarray(speed_mps, dtype=float)
    free_road = 1.0 - (speed / np.asarray(desired_speed_mps, dtype=float)) ** params.exponent
    dynamic = speed * params.time_headway_s + speed * approach_rate_mps / (
        2.0 * np.sqrt(params.max_accel_mps2 * params.comfortable_decel_mps2)
    )
    desired_gap = params.min_gap_m + np.maximum(dynamic, 0.0)
    gap = np.maximum(np.asarray(gap_m, dtype=float), 0.1)  # a touching car brakes at the limit
    accel = params.max_accel_mps2 * (free_road - (desired_gap / gap) ** 2)
    return np.clip(accel, -params.max_decel_mps2, params.max_accel_mps2)


def idm_equilibrium_gap(
    speed_mps: np.ndarray | float,
    desired_speed_mps: np.ndarray | float,
    params: IDMParams = IDMParams(),
) -> np.ndarray:
    """Bumper-to-bumper gap [m] at which IDM holds `speed_mps` behind a leader at the same speed.

    s_eq = (s0 + v T) / sqrt(1 - (v / v0)^delta); requires speed < desired speed.
    """
    ratio = np.asarray(speed_mps, dtype=float) / np.asarray(desired_speed_mps, dtype=float)
    if np.any(ratio >= 1.0):
        raise ValueError("equilibrium gap needs speed below the desired speed")
    free_road = 1.0 - ratio**params.exponent
    return (params.min_gap_m + np.asarray(speed_mps) * params.time_headway_s) / np.sqrt(free_road)
