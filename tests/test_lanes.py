"""Lanes of segments and arcs, the intersection and roundabout layouts, and their rendering,
checked against closed-form circle geometry and points known to lie on or off the road."""

import numpy as np
import pytest

from carlo_lite import (
    Arc,
    Intersection,
    Lane,
    LanePath,
    Roundabout,
    Segment,
    StraightRoad,
    join_lanes,
    render_layout,
)
from carlo_lite.render import GRASS_COLOR, ROAD_COLOR


def wrapped(angle):
    return np.angle(np.exp(1j * np.asarray(angle)))


def l_lane():
    """10 m along +x, a left quarter circle of radius 8 about (10, 8), then 5 m along +y."""
    return LanePath((0.0, 0.0), 0.0).straight(10).turn(8.0, np.pi / 2).straight(5).lane(3.0)


def test_arc_positions_and_headings_closed_form():
    lane = l_lane()
    assert lane.length_m == pytest.approx(15 + 4 * np.pi)
    theta = np.array([0.0, np.pi / 6, np.pi / 4, np.pi / 2])  # angle turned along the arc
    s = 10 + 8 * theta
    expected = np.stack([10 + 8 * np.sin(theta), 8 - 8 * np.cos(theta)], axis=-1)
    np.testing.assert_allclose(lane.position(s), expected, atol=1e-12)
    np.testing.assert_allclose(lane.heading_at(s), theta, atol=1e-12)
    # 1 m to the left on the arc is 1 m nearer the centre (10, 8)
    inner = lane.position(s, 1.0)
    np.testing.assert_allclose(np.hypot(inner[:, 0] - 10, inner[:, 1] - 8), 7.0)
    np.testing.assert_allclose(lane.position(lane.length_m), [18.0, 13.0], atol=1e-12)


def test_right_turn_arc_and_frame_beyond_the_ends():
    lane = LanePath((0.0, 0.0), 0.0).turn(5.0, -np.pi / 2).lane()
    np.testing.assert_allclose(lane.end, (5.0, -5.0), atol=1e-12)
    half = lane.length_m / 2
    r = 5 / np.sqrt(2)
    np.testing.assert_allclose(lane.position(half), [r, -5 + r], atol=1e-12)
    assert wrapped(lane.heading_at(half)) == pytest.approx(-np.pi / 4)
    # 2 m before the start (along -x) and 2 m past the end (along -y)
    np.testing.assert_allclose(lane.position([-2.0, lane.length_m + 2]), [[-2, 0], [5, -7]])
    s, d = lane.local_coordinates(np.array([[-2.0, 1.0], [6.0, -7.0]]))
    np.testing.assert_allclose(s, [-2.0, lane.length_m + 2])
    np.testing.assert_allclose(d, [1.0, 1.0])  # left of heading +x is +y, of heading -y is +x
    assert not lane.contains(np.array([[-2.0, 0.0], [5.0, -7.0]])).any()


def test_projection_round_trip_on_curved_lane():
    lane = l_lane()
    rng = np.random.default_rng(0)
    s = rng.uniform(0, lane.length_m, 2000)
    d = rng.uniform(-1.5, 1.5, 2000)  # within half the radius: projection is unique
    s2, d2 = lane.local_coordinates(lane.position(s, d))
    np.testing.assert_allclose(s2, s, atol=1e-9)
    np.testing.assert_allclose(d2, d, atol=1e-9)
    assert lane.contains(lane.position(s, d)).all()
    assert not lane.contains(lane.position(s, np.sign(d) * 1.6)).any()


def test_straight_lane_as_lane_matches_its_frame():
    road = StraightRoad(num_lanes=3, lane_width_m=3.0, length_m=100.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform([0, 0], [100, 9], (500, 2))
    for straight in road.lanes:
        lane = straight.as_lane()
        s, d = lane.local_coordinates(xy)
        s_ref, d_ref = straight.local_coordinates(xy)
        np.testing.assert_allclose(s, s_ref, atol=1e-12)
        np.testing.assert_allclose(d, d_ref, atol=1e-12)
    points = np.array([[10, 0.5], [10, 3.2], [10, 8.9], [10, 9.1], [10, -0.1], [-1, 1], [101, 1]])
    layout = road.layout()
    assert layout.on_road(points).tolist() == (road.lane_index(points) >= 0).tolist()
    assert layout.on_road(xy).all()


def test_bad_lanes_rejected():
    with pytest.raises(ValueError, match="starts"):
        Lane((Segment((0, 0), (1, 0)), Segment((2, 0), (3, 0))))
    with pytest.raises(ValueError):
        Lane(())
    with pytest.raises(ValueError):
        Arc((0, 0), -1.0, 0.0, 1.0)
    with pytest.raises(ValueError):
        Segment((1, 1), (1, 1))
    with pytest.raises(ValueError):
        join_lanes([])


def test_intersection_turns_connect_arms_on_closed_form_circles():
    junction = Intersection(lane_width_m=3.5, arm_length_m=50.0, corner_radius_m=4.0)
    b, w = 7.5, 3.5
    lanes = junction.layout.lanes
    assert len(lanes) == 20
    left = lanes["west_left"]
    assert left.length_m == pytest.approx((b + w / 2) * np.pi / 2)
    np.testing.assert_allclose(left.end, (w / 2, b), atol=1e-9)
    np.testing.assert_allclose(lanes["west_right"].end, (-w / 2, -b), atol=1e-9)
    # halfway round the left turn: 45 degrees on the circle about the corner (-b, b)
    mid = left.position(left.length_m / 2)
    r = b + w / 2
    np.testing.assert_allclose(mid, [-b + r / np.sqrt(2), b - r / np.sqrt(2)], atol=1e-9)
    route = junction.route("south", "left")
    assert junction.exit_arm("south", "left") == "west"
    np.testing.assert_allclose(route.end, (-b - 50, w / 2), atol=1e-9)
    assert wrapped(route.heading_at(route.length_m)) == pytest.approx(np.pi)
    assert route.length_m == pytest.approx(100 + r * np.pi / 2)
    with pytest.raises(ValueError):
        junction.route("up", "left")


def test_intersection_on_and_off_road_points():
    layout = Intersection(lane_width_m=3.5, arm_length_m=50.0, corner_radius_m=4.0).layout
    on = np.array([[0, 0], [-30, -1.0], [-30, 3.0], [1.0, 40], [4.5, 4.5], [-57, -3.4]])
    # (6.5, 6.5): the kerb, 1.4 m from the box corner (7.5, 7.5), inside the right turn's
    # inner edge at 4 m from it; (4.5, 4.5) is 4.2 m from it, on that turn
    off = np.array([[-30, 3.6], [-30, -3.6], [20, 20], [6.5, 6.5], [0, 58], [-58.0, -1]])
    assert layout.on_road(on).all()
    assert layout.off_road(off).all()


def test_roundabout_tangency_and_routes():
    rb = Roundabout(ring_radius_m=15.0, entry_radius_m=12.0, lane_offset_m=3.0, arm_length_m=40)
    lanes = rb.layout.lanes
    join = rb.join_angle
    assert np.tan(join) == pytest.approx(15 / np.sqrt(27**2 - 15**2))
    for i, angle in enumerate(rb.arm_angles):
        enter, leave = lanes[f"enter_{i}"], lanes[f"exit_{i}"]
        assert np.hypot(*enter.end) == pytest.approx(15.0)
        assert np.hypot(*leave.start) == pytest.approx(15.0)
        # the entry ends tangent to the ring, travelling counter-clockwise
        end_heading = enter.heading_at(enter.length_m)
        assert wrapped(end_heading - (angle + join + np.pi / 2)) == pytest.approx(0, abs=1e-9)
        axis = np.array([np.cos(angle), np.sin(angle)])
        assert np.dot(enter.start, axis) == pytest.approx(np.sqrt(27**2 - 15**2) + 40)
    route = rb.route(0, 1)
    ring_part = 15.0 * (np.pi / 2 - 2 * join)
    assert route.length_m == pytest.approx(2 * lanes["enter_0"].length_m + ring_part)
    np.testing.assert_allclose(route.end, lanes["exit_1"].end, atol=1e-9)
    full = rb.route(2, 2)
    assert full.length_m == pytest.approx(route.length_m + 15.0 * 3 * np.pi / 2)
    with pytest.raises(ValueError, match="apart"):
        Roundabout(arm_angles=(0.0, 0.5))


def test_roundabout_island_and_ring_on_off_road():
    layout = Roundabout(ring_radius_m=15.0, lane_width_m=4.0).layout
    angles = np.linspace(0, 2 * np.pi, 50, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    assert layout.on_road(15.0 * circle).all()
    assert layout.on_road(13.1 * circle).all()
    assert layout.off_road(12.5 * circle).all()  # central island
    assert layout.off_road(np.array([[0, 0], [30, 30], [40, 0]])).all()  # centre, corner, splitter
    assert layout.on_road(np.array([[40, 3], [40, -3], [3, 40]])).all()


@pytest.mark.parametrize("which", ["intersection", "roundabout"])
def test_render_layout_paints_road_where_lanes_are(which):
    layout = Intersection().layout if which == "intersection" else Roundabout().layout
    frame = render_layout(layout, width_px=120, height_px=100, center_xy=(0, 0), metres_per_px=1)
    assert frame.shape == (100, 120, 3) and frame.dtype == np.uint8

    def pixel(x, y):  # pixel whose centre is nearest world point (x, y)
        return frame[int(50 - y), int(60 + x)]

    if which == "intersection":
        on, off = [(-30.5, -1.5), (0.5, 0.5), (1.5, 30.5)], [(-30.5, 20.5), (20.5, -20.5)]
    else:
        on, off = [(15.5, 0.5), (-0.5, -15.5), (40.5, 3.5)], [(0.5, 0.5), (40.5, 20.5)]
    for x, y in on:
        assert tuple(pixel(x, y)) == ROAD_COLOR
    for x, y in off:
        assert tuple(pixel(x, y)) == GRASS_COLOR
    road = np.all(frame == ROAD_COLOR, axis=-1)
    assert 0.05 < road.mean() < 0.6
    with pytest.raises(ValueError):
        render_layout(layout, width_px=0)
