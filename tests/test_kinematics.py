"""Kinematic bicycle model against closed-form solutions."""

import numpy as np
import pytest

from carlo_lite import CarLimits, StraightRoad, World
from carlo_lite.kinematics import arc_length, bicycle_step, wrap_angle


def make_world(xy, heading, speed, **kwargs) -> World:
    road = StraightRoad(num_lanes=4, length_m=10_000.0)
    return World(
        road, np.asarray(xy, float), np.asarray(heading, float), np.asarray(speed, float), **kwargs
    )


def test_straight_line_constant_acceleration_matches_closed_form():
    accel, speed0, heading = 1.5, 5.0, 0.3
    world = make_world([[10.0, 5.0]], [heading], [speed0])
    for _ in range(40):
        world.step(np.array([[0.0, accel]]))
    t = 40 * world.dt
    distance = speed0 * t + 0.5 * accel * t**2
    expected = np.array([10.0 + distance * np.cos(heading), 5.0 + distance * np.sin(heading)])
    np.testing.assert_allclose(world.xy[0], expected, rtol=0, atol=1e-9)
    assert world.speed[0] == pytest.approx(speed0 + accel * t, abs=1e-12)
    assert world.heading[0] == pytest.approx(heading, abs=1e-12)


@pytest.mark.parametrize("steer", [0.05, 0.2, -0.35])
def test_constant_steering_traces_circle_of_radius_wheelbase_over_tan(steer):
    wheelbase = 2.7
    world = make_world([[0.0, 0.0]], [0.0], [8.0], wheelbase_m=wheelbase)
    radius = wheelbase / np.tan(abs(steer))
    center = np.array([0.0, np.sign(steer) * radius])  # centre to the left for positive steer
    positions = []
    for _ in range(300):
        world.step(np.array([[steer, 0.0]]))
        positions.append(world.xy[0].copy())
    distances = np.linalg.norm(np.array(positions) - center, axis=1)
    np.testing.assert_allclose(distances, radius, rtol=1e-9)
    # heading turned by arc length / radius (wrapped)
    turned = 300 * world.dt * 8.0 / radius * np.sign(steer)
    assert np.angle(np.exp(1j * (world.heading[0] - turned))) == pytest.approx(0.0, abs=1e-9)


def test_braking_stops_and_never_reverses():
    world = make_world([[0.0, 1.75]], [0.0], [3.0])
    for _ in range(30):
        world.step(np.array([[0.0, -8.0]]))
        assert world.speed[0] >= 0.0
    assert world.speed[0] == 0.0
    # stopping distance v^2 / (2 a), exactly, although the stop happens mid-step
    assert world.xy[0, 0] == pytest.approx(3.0**2 / (2 * 8.0), abs=1e-12)


def test_speed_capped_at_max_speed():
    limits = CarLimits(max_speed_mps=10.0)
    world = make_world([[0.0, 1.75]], [0.0], [9.8], limits=limits)
    world.step(np.array([[0.0, 4.0]]))  # reaches 10 after 0.05 s, then cruises
    assert world.speed[0] == 10.0
    assert world.xy[0, 0] == pytest.approx(
        9.8 * 0.05 + 0.5 * 4.0 * 0.05**2 + 10.0 * 0.05, abs=1e-12
    )
    for _ in range(10):
        world.step(np.array([[0.0, 4.0]]))
    assert world.speed[0] == 10.0


def test_arc_length_random_against_fine_integration():
    rng = np.random.default_rng(0)
    speed = rng.uniform(0, 20, 200)
    accel = rng.uniform(-8, 4, 200)
    distance, final = arc_length(speed, accel, 0.1, 20.0)
    sub = 100_000
    v = speed.copy()
    travelled = np.zeros_like(v)
    for _ in range(sub // 1000):  # midpoint rule on 1e-6 s sub-steps, vectorised in chunks
        for _ in range(1000):
            v_next = np.clip(v + accel * (0.1 / sub), 0, 20.0)
            travelled += 0.5 * (v + v_next) * (0.1 / sub)
            v = v_next
    np.testing.assert_allclose(distance, travelled, atol=1e-6)
    np.testing.assert_allclose(final, v, atol=1e-9)


def test_controls_are_clipped_to_limits():
    limits = CarLimits()
    a = make_world([[0.0, 1.75]], [0.0], [10.0])
    b = make_world([[0.0, 1.75]], [0.0], [10.0])
    a.step(np.array([[5.0, 100.0]]))
    b.step(np.array([[limits.max_steer_rad, limits.max_accel_mps2]]))
    np.testing.assert_array_equal(a.state, b.state)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_control_raises_naming_the_car(bad):
    world = make_world([[0.0, 1.75], [20.0, 1.75], [40.0, 1.75]], [0, 0, 0], [5, 5, 5])
    controls = np.zeros((3, 2))
    controls[2, 1] = bad
    before = world.state
    with pytest.raises(ValueError, match="car 2"):
        world.step(controls)
    np.testing.assert_array_equal(world.state, before)  # nothing moved


def test_wrong_control_shape_raises():
    world = make_world([[0.0, 1.75]], [0.0], [5.0])
    with pytest.raises(ValueError, match="shape"):
        world.step(np.zeros((2, 2)))


def test_step_is_deterministic_and_vectorised_equals_single():
    rng = np.random.default_rng(1)
    n = 22
    xy = rng.uniform(0, 100, (n, 2))
    heading = rng.uniform(-np.pi, np.pi, n)
    speed = rng.uniform(0, 20, n)
    controls = np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-9, 5, n)])
    runs = []
    for _ in range(2):
        world = make_world(xy, heading, speed)
        for _ in range(50):
            world.step(controls)
        runs.append(world.state)
    np.testing.assert_array_equal(runs[0], runs[1])
    # car 5 stepped alone gives bit-identical results: no coupling between cars in the step
    alone = make_world(xy[5:6], heading[5:6], speed[5:6])
    for _ in range(50):
        alone.step(controls[5:6])
    np.testing.assert_array_equal(alone.state[0], runs[0][5])


def test_bicycle_step_pure_function_does_not_modify_inputs():
    xy = np.array([[1.0, 2.0]])
    heading = np.array([0.1])
    speed = np.array([3.0])
    controls = np.array([[0.1, 1.0]])
    bicycle_step(xy, heading, speed, controls, np.array([2.7]), 0.1, 40.0)
    assert xy.tolist() == [[1.0, 2.0]] and speed.tolist() == [3.0] and heading.tolist() == [0.1]


def test_wrap_angle_is_the_modulo_bit_for_bit():
    """wrap_angle skips numpy's slow float modulo for angles in (-3 pi, 3 pi), what a step or a
    difference of wrapped angles produces; over that range and its edges (and beyond, where it
    takes the modulo) the result is `(a + pi) % (2 pi) - pi` bit for bit, zero's sign included."""
    rng = np.random.default_rng(0)
    headings = rng.uniform(-np.pi, np.pi, (2, 200_000))
    edges = np.array([-np.pi, np.nextafter(np.pi, 0.0), 0.0, -0.0, 1e-300, -1e-300])
    differences = np.concatenate(
        [headings[1] - headings[0], np.subtract.outer(edges, edges).ravel()]
    )  # (-2 pi, 2 pi)
    steps = rng.uniform(-3.0 * np.pi + 1e-9, 3.0 * np.pi - 1e-9, 200_000)
    far = rng.uniform(-40.0, 40.0, 1000)  # the modulo's own path
    for angles in (differences, steps, far, np.array(2.5), np.array([])):
        want = (angles + np.pi) % (2.0 * np.pi) - np.pi
        got = wrap_angle(angles)
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(np.signbit(got), np.signbit(want))
        assert np.all((got >= -np.pi) & (got < np.pi))
