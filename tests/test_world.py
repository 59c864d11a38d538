"""World state handling: copies, resets, deactivation, pickling, rendering."""

import pickle

import numpy as np
import pytest

from carlo_lite import ROLE_COLORS, StraightRoad, World, render_rgb


def small_world() -> World:
    road = StraightRoad(num_lanes=4, length_m=500.0)
    xy = np.array([[20.0, 5.25], [30.0, 8.75], [10.0, 1.75], [40.0, 12.25]])
    roles = ["main_green", "main_brown", "distractor", "distractor"]
    return World(road, xy, np.zeros(4), np.array([10.0, 11.0, 12.0, 13.0]), roles=roles)


def test_state_layout_and_readonly_views():
    world = small_world()
    assert world.state.shape == (4, 4)
    np.testing.assert_array_equal(world.state[:, 3], [10, 11, 12, 13])
    with pytest.raises(ValueError):
        world.xy[0, 0] = 1.0


def test_copy_is_independent():
    world = small_world()
    clone = world.copy()
    clone.step(np.tile([0.1, 1.0], (4, 1)))
    assert clone.step_count == 1 and world.step_count == 0
    assert not np.array_equal(clone.state, world.state)
    # stepping the original the same way gives the same result as the clone
    world.step(np.tile([0.1, 1.0], (4, 1)))
    np.testing.assert_array_equal(clone.state, world.state)


def test_set_state_resets_clock_and_clips_speed():
    world = small_world()
    world.step(np.zeros((4, 2)))
    state = world.state
    state[0, 3] = -5.0
    world.set_state(state)
    assert world.step_count == 0 and world.speed[0] == 0.0
    with pytest.raises(ValueError):
        world.set_state(np.full((4, 4), np.nan))


def test_deactivated_car_is_frozen_and_nan_control_ignored():
    world = small_world()
    world.deactivate(1)
    before = world.state[1]
    controls = np.zeros((4, 2))
    controls[1] = np.nan  # a removed car's control is ignored
    world.step(controls)
    np.testing.assert_array_equal(world.state[1], before)
    assert world.state[0, 0] > 20.0


def test_pickle_round_trip_keeps_behaviour():
    world = small_world()
    world.step(np.tile([0.05, 0.5], (4, 1)))
    clone = pickle.loads(pickle.dumps(world))
    for w in (world, clone):
        for _ in range(5):
            w.step(np.tile([0.05, 0.5], (4, 1)))
    np.testing.assert_array_equal(world.state, clone.state)
    assert clone.collisions().tolist() == world.collisions().tolist()


def test_render_without_display_shape_dtype_and_colours(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    world = small_world()
    frame = render_rgb(world, width_px=400, height_px=120)
    assert frame.shape == (120, 400, 3) and frame.dtype == np.uint8
    colours = {tuple(c) for c in frame.reshape(-1, 3)}
    assert ROLE_COLORS["main_green"] in colours
    assert ROLE_COLORS["main_brown"] in colours
    assert ROLE_COLORS["distractor"] in colours


def test_render_places_car_at_its_pixel():
    world = small_world()
    frame = render_rgb(
        world, width_px=200, height_px=100, center_xy=(20.0, 5.25), metres_per_px=0.1
    )
    # the green car is centred in the frame
    assert tuple(frame[50, 100]) == ROLE_COLORS["main_green"]
    world.deactivate(0)
    frame = render_rgb(
        world, width_px=200, height_px=100, center_xy=(20.0, 5.25), metres_per_px=0.1
    )
    assert tuple(frame[50, 100]) != ROLE_COLORS["main_green"]


def test_render_rejects_empty_frame():
    with pytest.raises(ValueError):
        render_rgb(small_world(), width_px=0)


def test_dt_and_sizes_validated():
    road = StraightRoad()
    with pytest.raises(ValueError):
        World(road, np.zeros((1, 2)), np.zeros(1), np.zeros(1), dt=0.0)
    with pytest.raises(ValueError):
        World(road, np.zeros((2, 2)), np.zeros(2), np.zeros(2), length_m=[4.5, -1.0])
    with pytest.raises(ValueError):
        World(road, np.zeros((2, 2)), np.zeros(2), np.zeros(2), roles=["a"])


def test_human_viewer_opens_and_closes_with_dummy_video_driver(monkeypatch):
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    from carlo_lite import HumanViewer

    viewer = HumanViewer(fps=1000.0)
    frame = render_rgb(small_world(), width_px=64, height_px=32)
    viewer.show(frame)
    import pygame

    shown = pygame.surfarray.array3d(pygame.display.get_surface()).swapaxes(0, 1)
    np.testing.assert_array_equal(shown, frame)
    viewer.close()
