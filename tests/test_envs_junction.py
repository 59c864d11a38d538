"""The environments on a road layout (the junction scenarios): observation bounds, the route
reward, square frames and the manual's wording; the straight road's bounds for contrast."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios import double_merge_v0, left_turn_v0


# --- junction scenarios: bounds, reward and frames of a road layout ---------------------------
def test_straight_road_bounds_are_the_road_box() -> None:
    """[0, 600] x [0, 4 lanes x 3.5 m]; relative positions up to the box's extent."""
    low = double_merge_v0.parallel_env().observation_space("car_0").low
    high = double_merge_v0.parallel_env().observation_space("car_0").high
    np.testing.assert_array_equal(low[:9], np.float32([0, 0, -np.pi, 0, 0, -600, -14, -np.pi, -40]))
    np.testing.assert_array_equal(high[:9], np.float32([600, 14, np.pi, 40, 1, 600, 14, np.pi, 40]))


def test_left_turn_bounds_are_the_intersection_box() -> None:
    """Arms of 200 m beyond a box of half width 3.5 + 4 m, lanes 3.5 m wide: the surface reaches
    200 + 7.5 + 1.75 = 209.25 m from the centre each way, rounded out to 210 m."""
    space = left_turn_v0.parallel_env().observation_space("car_0")
    np.testing.assert_array_equal(space.low[:7], np.float32([-210, -210, -np.pi, 0, 0, -420, -420]))
    np.testing.assert_array_equal(space.high[:7], np.float32([210, 210, np.pi, 40, 1, 420, 420]))


def test_junction_reward_is_speed_along_the_route() -> None:
    """The turning car starts on the south approach, whose route heads north (pi / 2): its
    progress reward is 0.1 v cos(heading - pi / 2) / 40, not the road's v cos(heading)."""
    env = left_turn_v0.parallel_env()
    env.reset(seed=3)
    _, rewards, *_ = env.step(env.unwrapped.expert_actions())
    _, _, heading, speed = env.unwrapped.world.state[0]
    assert abs(heading - np.pi / 2) < 0.05 and speed > 5.0  # still on its straight approach
    expected = 0.1 * speed * np.cos(heading - np.pi / 2) / 40.0
    assert rewards["car_0"] == pytest.approx(expected, rel=1e-9)
    assert rewards["car_0"] > 0.5 * 0.1 * speed / 40.0


def test_junction_frame_is_a_square_centred_on_the_junction() -> None:
    """400 px show 120 m: the centre pixel lies inside the junction box (road), a corner pixel
    60 m out diagonally lies between the arms (grass)."""
    from carlo_lite.render import GRASS_COLOR, ROAD_COLOR

    env = left_turn_v0.parallel_env(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 400, 3)
    np.testing.assert_array_equal(frame[200, 200], ROAD_COLOR)
    np.testing.assert_array_equal(frame[0, 0], GRASS_COLOR)
    np.testing.assert_array_equal(frame[399, 399], GRASS_COLOR)
    vector = left_turn_v0.vector_env(num_envs=2)
    vector.reset(seed=0)
    np.testing.assert_array_equal(vector.render(0), frame)


def test_junction_manual_speaks_of_world_coordinates_and_routes() -> None:
    manual = " ".join(left_turn_v0.raw_env.__doc__.split())
    assert "ego x [m] (world frame of the layout)" in manual
    assert "along the road" not in manual and "lanes 0 and" not in manual
    assert "`car_4` ... `car_15` are distractors in columns of 3" in manual
    assert "cos(heading - route heading)" in manual
