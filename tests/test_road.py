"""Road geometry: lane centres, lane lookup and road-frame coordinates."""

import numpy as np
import pytest

from carlo_lite import StraightLane, StraightRoad


def test_lane_centres_and_width():
    road = StraightRoad(num_lanes=4, lane_width_m=3.5, length_m=300.0)
    assert [road.lane_center_y(i) for i in range(4)] == [1.75, 5.25, 8.75, 12.25]
    assert road.width_m == 14.0
    assert road.lateral_bounds == (0.0, 14.0)
    assert road.marking_lines_y() == (3.5, 7.0, 10.5)
    with pytest.raises(IndexError):
        road.lane_center_y(4)


def test_lane_index_including_off_road():
    road = StraightRoad(num_lanes=3, lane_width_m=3.0, length_m=100.0)
    points = np.array(
        [[10, 0.5], [10, 3.2], [10, 8.9], [10, 9.1], [10, -0.1], [-1, 1.0], [101, 1.0]]
    )
    assert road.lane_index(points).tolist() == [0, 1, 2, -1, -1, -1, -1]


def test_road_frame_round_trip_and_lane_coordinates():
    road = StraightRoad()
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (50, 2))
    s, d = road.to_road_frame(xy)
    np.testing.assert_allclose(road.from_road_frame(s, d), xy)
    lane = road.lanes[2]
    ls, ld = lane.local_coordinates(xy)
    np.testing.assert_allclose(ld, xy[:, 1] - road.lane_center_y(2))
    np.testing.assert_allclose(lane.position(ls, ld), xy)


def test_diagonal_lane_geometry():
    lane = StraightLane(start=(0.0, 0.0), end=(3.0, 4.0), width_m=3.5)
    assert lane.length_m == pytest.approx(5.0)
    assert lane.heading_at(0.0) == pytest.approx(np.arctan2(4, 3))
    # 1 m to the left of the point 5 m along
    np.testing.assert_allclose(lane.position(5.0, 1.0), [3.0 - 0.8, 4.0 + 0.6])
    s, d = lane.local_coordinates(np.array([2.2, 4.6]))
    assert (s, d) == pytest.approx((5.0, 1.0))


def test_invalid_road_rejected():
    with pytest.raises(ValueError):
        StraightRoad(num_lanes=0)
    with pytest.raises(ValueError):
        StraightRoad(lane_width_m=-1.0)
