"""Controllers against hand-computed values, finite differences and closed-loop simulations.

The closed loops use a fine-step Euler integration of the bicycle ODE written here, independent
of carlo_lite, with each control held for one control period (zero-order hold).
"""

from __future__ import annotations

import numpy as np
import pytest

from scenarios.controllers import (
    IDMParams,
    LateralGains,
    idm_accel,
    idm_equilibrium_gap,
    lane_change_reference,
    lateral_steering,
    quintic_blend,
    speed_tracking_accel,
)

WHEELBASE_M = 2.7


def hold_and_integrate(
    state: np.ndarray, steer: float, accel: float, period_s: float
) -> np.ndarray:
    """Euler-integrate [lateral, heading, speed, longitudinal] over one held control period."""
    lateral, heading, speed, along = state
    fine_dt = 1e-3
    for _ in range(round(period_s / fine_dt)):
        along += speed * np.cos(heading) * fine_dt
        lateral += speed * np.sin(heading) * fine_dt
        heading += speed * np.tan(steer) / WHEELBASE_M * fine_dt
        speed = max(speed + accel * fine_dt, 0.0)
    return np.array([lateral, heading, speed, along])


def test_quintic_blend_endpoints_midpoint_and_derivatives() -> None:
    value, slope, curvature = quintic_blend(np.array([-1.0, 0.0, 0.5, 1.0, 2.0]))
    np.testing.assert_allclose(value, [0.0, 0.0, 0.5, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(slope, [0.0, 0.0, 1.875, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(curvature, np.zeros(5), atol=1e-12)
    tau = np.linspace(0.05, 0.95, 19)
    eps = 1e-6
    above, below, here = quintic_blend(tau + eps), quintic_blend(tau - eps), quintic_blend(tau)
    np.testing.assert_allclose(here[1], (above[0] - below[0]) / (2 * eps), rtol=1e-6)
    np.testing.assert_allclose(here[2], (above[1] - below[1]) / (2 * eps), rtol=1e-5, atol=1e-8)


def test_lane_change_reference_moves_by_the_shift_and_its_rate_integrates_to_it() -> None:
    times = np.linspace(0.0, 6.0, 6001)
    reference, rate, accel = lane_change_reference(times, 1.0, 3.0, from_m=5.25, to_m=8.75)
    assert reference[0] == 5.25 and reference[-1] == 8.75
    assert np.all(reference[times <= 1.0] == 5.25) and np.all(reference[times >= 4.0] == 8.75)
    integral = np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(times))
    assert integral == pytest.approx(3.5, abs=1e-6)
    assert rate.max() == pytest.approx(1.875 * 3.5 / 3.0, rel=1e-6)
    assert np.sum(0.5 * (accel[1:] + accel[:-1]) * np.diff(times)) == pytest.approx(0, abs=1e-6)
    assert accel.max() == pytest.approx(10.0 / np.sqrt(3.0) * 3.5 / 9.0, rel=1e-5)
    with pytest.raises(ValueError):
        lane_change_reference(0.0, 0.0, 0.0, 0.0, 1.0)


def test_lateral_steering_is_zero_on_the_reference_and_steers_towards_it() -> None:
    steer = lateral_steering(
        lateral_m=np.array([1.75, 1.75, 1.75]),
        heading_rad=np.zeros(3),
        speed_mps=np.full(3, 10.0),
        target_lateral_m=np.array([1.75, 3.0, 0.5]),
        target_rate_mps=0.0,
        wheelbase_m=WHEELBASE_M,
    )
    assert steer[0] == 0.0
    assert steer[1] > 0.0 > steer[2]  # left of the car is +lateral and +steering
    assert steer[1] == pytest.approx(-steer[2])


def test_lateral_steering_matches_the_hand_computed_cascade() -> None:
    gains = LateralGains()
    # error 0.5 m at 10 m/s: desired lateral speed 0.4 m/s -> heading asin(0.04);
    # yaw rate 2.5 * asin(0.04); steering atan(yaw_rate * 2.7 / 10).
    expected = np.arctan(2.5 * np.arcsin(0.04) * 2.7 / 10.0)
    steer = lateral_steering(0.0, 0.0, 10.0, 0.5, 0.0, WHEELBASE_M, gains)
    assert float(steer) == pytest.approx(expected, rel=1e-12)
    # a huge error is capped at max_heading: yaw rate 2.5 * 0.35 at most
    capped = lateral_steering(0.0, 0.0, 10.0, 100.0, 0.0, WHEELBASE_M, gains)
    assert float(capped) == pytest.approx(np.arctan(2.5 * 0.35 * 2.7 / 10.0), rel=1e-12)


@pytest.mark.parametrize("period_s", [0.1, 0.2, 0.3])
@pytest.mark.parametrize("speed", [8.0, 12.0])
def test_closed_loop_lane_change_tracks_and_settles(period_s: float, speed: float) -> None:
    """One 3.5 m lane change in 3 s (peak lateral speed 2.2 m/s, feasible from 8 m/s up)."""
    state = np.array([1.75, 0.0, speed, 0.0])  # lateral, heading, speed, longitudinal
    errors, laterals = [], []
    for step in range(round(10.0 / period_s)):
        target, rate, accel = lane_change_reference(step * period_s, 1.0, 3.0, 1.75, 5.25)
        steer = lateral_steering(
            state[0], state[1], state[2], target, rate, WHEELBASE_M, target_accel_mps2=accel
        )
        state = hold_and_integrate(state, float(steer), 0.0, period_s)
        next_target = lane_change_reference((step + 1) * period_s, 1.0, 3.0, 1.75, 5.25)[0]
        errors.append(abs(state[0] - next_target))
        laterals.append(state[0])
    assert max(errors) < 0.5 * period_s + 0.01  # the hold delays tracking by ~half a period
    assert max(laterals) < 5.25 + 0.1  # no real overshoot
    assert abs(laterals[-1] - 5.25) < 0.01 and abs(state[1]) < 0.005  # settled


def test_feed_forward_of_the_reference_acceleration_reduces_tracking_error() -> None:
    worst = []
    for use_accel in (False, True):
        state, error = np.array([1.75, 0.0, 10.0, 0.0]), 0.0
        for step in range(50):
            target, rate, accel = lane_change_reference(step * 0.1, 0.5, 3.0, 1.75, 5.25)
            steer = lateral_steering(
                state[0],
                state[1],
                state[2],
                target,
                rate,
                WHEELBASE_M,
                target_accel_mps2=accel if use_accel else 0.0,
            )
            state = hold_and_integrate(state, float(steer), 0.0, 0.1)
            next_target = lane_change_reference((step + 1) * 0.1, 0.5, 3.0, 1.75, 5.25)[0]
            error = max(error, abs(state[0] - next_target))
        worst.append(error)
    assert worst[1] < 0.25 * worst[0]


def test_speed_tracking_accel_hand_values() -> None:
    accel = speed_tracking_accel(np.array([10.0, 10.0, 10.0, 0.0]), 11.0, 1.5, 2.0, 5.0)
    np.testing.assert_allclose(accel, [1.5, 1.5, 1.5, 2.0])
    accel = speed_tracking_accel(np.array([10.0, 20.0]), np.array([10.0, 10.0]), 1.5, 2.0, 5.0)
    np.testing.assert_allclose(accel, [0.0, -5.0])


def test_idm_free_road_and_equilibrium_hand_values() -> None:
    params = IDMParams(time_headway_s=1.5, min_gap_m=2.0, max_accel_mps2=2.0)
    free = idm_accel(np.array([0.0, 12.0]), 12.0, np.full(2, np.inf), np.zeros(2), params)
    np.testing.assert_allclose(free, [2.0, 0.0], atol=1e-12)
    # s_eq = (2 + 10 * 1.5) / sqrt(1 - (10/12)^4) = 17 / 0.719549... = 23.6259... m
    gap = idm_equilibrium_gap(10.0, 12.0, params)
    assert float(gap) == pytest.approx(17.0 / np.sqrt(1.0 - (10.0 / 12.0) ** 4), rel=1e-12)
    assert float(gap) == pytest.approx(23.6259, abs=1e-3)
    assert float(idm_accel(10.0, 12.0, gap, 0.0, params)) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError):
        idm_equilibrium_gap(12.0, 12.0, params)


def test_idm_closing_in_hand_value_and_braking_limit() -> None:
    params = IDMParams()
    # v = 10, v0 = 12, dv = 2, s = 20: s* = 2 + 15 + 10 * 2 / (2 sqrt(6)) = 21.0825 m
    desired_gap = 2.0 + 15.0 + 20.0 / (2.0 * np.sqrt(6.0))
    expected = 2.0 * (1.0 - (10.0 / 12.0) ** 4 - (desired_gap / 20.0) ** 2)
    assert float(idm_accel(10.0, 12.0, 20.0, 2.0, params)) == pytest.approx(expected, rel=1e-12)
    assert float(idm_accel(10.0, 12.0, 0.0, 0.0, params)) == -params.max_decel_mps2
    assert float(idm_accel(10.0, 12.0, -3.0, 0.0, params)) == -params.max_decel_mps2


@pytest.mark.parametrize("leader_decel", [3.0, 6.0])
def test_idm_follower_stops_behind_a_braking_leader_without_touching(leader_decel: float) -> None:
    params = IDMParams(time_headway_s=1.2)
    period = 0.3
    follower = np.array([0.0, 0.0, 12.0, 0.0])  # lateral, heading, speed, longitudinal
    gap0 = float(idm_equilibrium_gap(12.0, 14.0, params))
    leader_along, leader_speed = gap0 + 4.5, 12.0
    min_gap = np.inf
    for step in range(round(20.0 / period)):
        leader_accel = -leader_decel if step * period >= 2.0 else 0.0
        gap = leader_along - follower[3] - 4.5
        accel = idm_accel(follower[2], 14.0, gap, follower[2] - leader_speed, params)
        follower = hold_and_integrate(follower, 0.0, float(accel), period)
        # the leader's motion under constant deceleration, stopped at zero speed
        stop_time = min(period, leader_speed / leader_decel) if leader_accel else period
        leader_along += leader_speed * stop_time + 0.5 * leader_accel * stop_time**2
        leader_speed = max(leader_speed + leader_accel * period, 0.0)
        min_gap = min(min_gap, leader_along - follower[3] - 4.5)
    assert leader_speed == 0.0 and follower[2] < 0.05  # both stopped
    assert min_gap > 1.0  # kept a margin the whole time
