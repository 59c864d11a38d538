"""carlo_lite.BatchedWorld: every scene evolves as it would alone (one `World` per scene: the
same states bit for bit under the same controls, clipping, stopping, turning; the same
collisions and off-road cars, pairs only within a scene), removed cars and restarts per scene,
and numpy's vectorised functions giving each element the same result whatever the array's
length or stride (what makes a scene independent of its batch). Kinematics and collisions
against closed form and a separating-axis check: test_kinematics.py, test_collision.py."""

from __future__ import annotations

import numpy as np
import pytest

from carlo_lite import BatchedWorld, StraightRoad, World

ROAD = StraightRoad(num_lanes=4, lane_width_m=3.5, length_m=200.0)
LENGTHS = np.array([4.5, 4.5, 5.0, 3.8, 4.5, 6.0])  # one body per car, the same in every scene
WIDTHS = np.array([1.8, 1.8, 2.0, 1.6, 1.8, 2.2])


def scenes(rng: np.random.Generator, num_scenes: int) -> np.ndarray:
    """(B, 6, 4) states: cars in random lanes, some close enough to touch, some near an edge."""
    num_cars = len(LENGTHS)
    state = np.zeros((num_scenes, num_cars, 4))
    state[..., 0] = rng.uniform(2.0, 60.0, (num_scenes, num_cars))
    state[..., 1] = rng.uniform(0.6, 13.4, (num_scenes, num_cars))
    state[..., 2] = rng.uniform(-0.4, 0.4, (num_scenes, num_cars)) + 2 * np.pi * rng.integers(
        -1, 2, (num_scenes, num_cars)
    )  # wrapped at the start
    state[..., 3] = rng.uniform(-1.0, 45.0, (num_scenes, num_cars))  # clipped to [0, 40]
    state[0, 1, :2] = state[0, 0, :2] + (3.0, 0.5)  # scene 0: two cars overlap at once
    return state


def worlds_of(state: np.ndarray) -> list[World]:
    return [
        World(ROAD, s[:, :2], s[:, 2], s[:, 3], length_m=LENGTHS, width_m=WIDTHS, wheelbase_m=2.9)
        for s in state
    ]


def test_every_scene_steps_and_collides_like_its_own_world():
    rng = np.random.default_rng(7)
    state = scenes(rng, 9)
    batched = BatchedWorld(ROAD, state, length_m=LENGTHS, width_m=WIDTHS, wheelbase_m=2.9)
    worlds = worlds_of(state)
    seen_hit, seen_off, seen_clean = False, False, False
    for step in range(60):
        for b, world in enumerate(worlds):
            np.testing.assert_array_equal(batched.state[b], world.state, err_msg=f"{step}, {b}")
        hit, off = batched.incidents()  # (B, N) each
        for b, world in enumerate(worlds):
            world_hit, world_off = world.incidents()
            np.testing.assert_array_equal(hit[b], world_hit, err_msg=f"step {step}, scene {b}")
            np.testing.assert_array_equal(off[b], world_off, err_msg=f"step {step}, scene {b}")
        seen_hit |= hit.any()
        seen_off |= off.any()
        seen_clean |= not (hit | off).any(axis=1).all()
        # out-of-limit steering and acceleration, hard braking to a stop, float32 like the expert
        controls = rng.uniform((-0.7, -10.0), (0.7, 6.0), (9, len(LENGTHS), 2)).astype(np.float32)
        batched.step(controls)
        for world, scene_controls in zip(worlds, controls):
            world.step(scene_controls)
    assert seen_hit and seen_off and seen_clean  # the checks met every kind of scene
    assert (batched.step_count == 60).all() and (batched.time_s == worlds[0].time_s).all()


def test_pairs_never_cross_scenes():
    state = np.zeros((2, 2, 4))
    state[:, 0] = (20.0, 5.25, 0.0, 10.0)  # car 0 of both scenes at the same place
    state[:, 1] = (60.0, 8.75, 0.0, 10.0)
    batched = BatchedWorld(ROAD, state)
    hit, off = batched.incidents()
    assert not hit.any() and not off.any()


def test_scene_is_an_independent_world_of_the_same_state():
    rng = np.random.default_rng(3)
    state = scenes(rng, 4)
    batched = BatchedWorld(ROAD, state, length_m=LENGTHS, width_m=WIDTHS)
    controls = rng.uniform(-1.0, 1.0, (4, len(LENGTHS), 2))
    batched.step(controls)
    world = World.from_scene(batched, 2)
    np.testing.assert_array_equal(world.state, batched.state[2])
    assert world.time_s == batched.time_s[2]
    world.step(controls[2])
    batched.step(controls)
    np.testing.assert_array_equal(world.state, batched.state[2])
    for outside in (-1, 4):
        with pytest.raises(IndexError, match=f"scene {outside} out of range"):
            World.from_scene(batched, outside)


def test_views_are_read_only_and_bad_controls_are_named():
    batched = BatchedWorld(ROAD, scenes(np.random.default_rng(0), 3))
    assert batched.xy.shape == (3, 6, 2) and batched.speed.shape == (3, 6)
    with pytest.raises(ValueError):
        batched.speed[0, 0] = 1.0
    with pytest.raises(ValueError, match="shape"):
        batched.step(np.zeros((6, 2)))
    controls = np.zeros((3, 6, 2))
    controls[2, 4, 1] = np.nan
    with pytest.raises(ValueError, match="scene 2, car 4"):
        batched.step(controls)
    with pytest.raises(ValueError, match="state"):
        BatchedWorld(ROAD, np.zeros((6, 4)))


def test_removed_cars_freeze_ignore_their_controls_and_never_collide():
    state = np.zeros((3, 2, 4))
    state[:, 0] = (20.0, 5.25, 0.0, 10.0)
    state[:, 1] = (21.0, 5.25, 0.0, 10.0)  # overlapping car 0 in every scene
    batched = BatchedWorld(ROAD, state, roles=("a", "b"))
    hit, _ = batched.incidents()
    assert hit.all()
    removed = np.zeros((3, 2), dtype=bool)
    removed[1, 1] = True
    batched.deactivate(removed)
    np.testing.assert_array_equal(batched.active, ~removed)
    hit, _ = batched.incidents()
    np.testing.assert_array_equal(hit, [[True, True], [False, False], [True, True]])
    controls = np.zeros((3, 2, 2))
    controls[:, :, 1] = 1.0
    controls[1, 1] = np.nan  # a removed car's control is ignored ...
    batched.step(controls)
    assert batched.state[1, 1, 0] == 21.0 and batched.state[0, 1, 0] > 21.0
    controls[1, 0] = np.nan  # ... an active one's is not, and the error names it
    with pytest.raises(ValueError, match=r"scene 1, car 0 \(a\) has a non-finite control"):
        batched.step(controls)
    with pytest.raises(ValueError, match="mask"):
        batched.deactivate(np.zeros(2, dtype=bool))


def test_restart_starts_chosen_scenes_over_and_leaves_the_others():
    rng = np.random.default_rng(11)
    state = scenes(rng, 4)
    batched = BatchedWorld(ROAD, state, length_m=LENGTHS, width_m=WIDTHS)
    controls = rng.uniform(-0.3, 0.3, (4, len(LENGTHS), 2))
    for _ in range(5):
        batched.step(controls)
    removed = np.zeros((4, len(LENGTHS)), dtype=bool)
    removed[[1, 2], 0] = True
    batched.deactivate(removed)
    before = batched.state
    fresh = scenes(np.random.default_rng(12), 2)
    batched.restart([2, 0], fresh)
    np.testing.assert_array_equal(batched.step_count, [0, 5, 0, 5])
    np.testing.assert_array_equal(batched.active[:, 0], [True, False, True, True])
    alone = BatchedWorld(ROAD, fresh, length_m=LENGTHS, width_m=WIDTHS)  # the restarted two
    np.testing.assert_array_equal(batched.state[[2, 0]], alone.state)
    np.testing.assert_array_equal(batched.state[[1, 3]], before[[1, 3]])
    batched.step(controls)
    alone.step(controls[[2, 0]])
    np.testing.assert_array_equal(batched.state[[2, 0]], alone.state)
    with pytest.raises(ValueError, match=r"state must be a finite \(1, 6, 4\) array"):
        batched.restart([1], fresh)


@pytest.mark.parametrize(
    "function",
    [np.sin, np.cos, np.tan, np.arctan, np.arcsin, np.sqrt, lambda x: x**3, lambda x: x**2],
    ids=["sin", "cos", "tan", "arctan", "arcsin", "sqrt", "cube", "square"],
)
def test_vectorised_functions_do_not_depend_on_length_or_stride(function):
    """What the batched world relies on: an element's result is the same in an array of any
    length, contiguous or strided (numpy's SIMD loops with their remainder handling)."""
    values = np.random.default_rng(1).uniform(0.0, 1.0, 4099)
    whole = function(values)
    strided = np.empty((len(values), 2))
    strided[:, 0] = values
    np.testing.assert_array_equal(function(strided[:, 0]), whole)
    for length in (1, 2, 3, 7, 8, 9, 22, 63, 64, 65):
        pieces = [function(values[i : i + length]) for i in range(0, len(values), length)]
        np.testing.assert_array_equal(np.concatenate(pieces), whole, err_msg=f"length {length}")
