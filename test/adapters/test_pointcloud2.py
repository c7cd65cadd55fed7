"""Round trips and bad layouts for the PointCloud2 adapter, on in-memory messages."""

import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2, PointField

from msg_adapters.pointcloud2 import (cloud_from_msg, msg_from_cloud, pack_rgb, surface_from_msg,
                                      surface_to_msg, unpack_rgb)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Surface


def _realsense_cloud(points, rgb_u8, height=1, bigendian=False):
    """Build a cloud the way realsense-ros lays it out: x y z rgb(float32 packed), 16 B + pad."""
    n = len(points)
    order = '>' if bigendian else '<'
    dtype = np.dtype({'names': ['x', 'y', 'z', 'rgb'],
                      'formats': [order + 'f4'] * 3 + [order + 'u4'],
                      'offsets': [0, 4, 8, 16], 'itemsize': 20})
    arr = np.zeros(n, dtype=dtype)
    arr['x'], arr['y'], arr['z'] = points.T
    rgb_u8 = rgb_u8.astype(np.uint32)
    arr['rgb'] = (rgb_u8[:, 0] << 16) | (rgb_u8[:, 1] << 8) | rgb_u8[:, 2]
    msg = PointCloud2()
    msg.header.frame_id = 'camera_depth_optical_frame'
    msg.height, msg.width = height, n // height
    msg.fields = [PointField(name='x', offset=0, datatype=PointField.FLOAT32, count=1),
                  PointField(name='y', offset=4, datatype=PointField.FLOAT32, count=1),
                  PointField(name='z', offset=8, datatype=PointField.FLOAT32, count=1),
                  PointField(name='rgb', offset=16, datatype=PointField.FLOAT32, count=1)]
    msg.is_bigendian = bigendian
    msg.point_step = 20
    msg.row_step = 20 * msg.width
    msg.data = arr.tobytes()
    return msg


@pytest.fixture
def rng():
    return np.random.default_rng(7)


@pytest.mark.parametrize('bigendian', [False, True])
def test_realsense_layout_reads_points_and_colours(rng, bigendian):
    pts = rng.uniform(-1, 1, (60, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (60, 3))
    cloud = cloud_from_msg(_realsense_cloud(pts, rgb, bigendian=bigendian))
    np.testing.assert_allclose(cloud.points, pts, rtol=0, atol=0)
    np.testing.assert_allclose(cloud.rgb * 255.0, rgb, atol=1e-9)
    assert cloud.frame_id == 'camera_depth_optical_frame'
    assert cloud.normals is None


def test_organised_cloud_keeps_image_layout_and_nan_can_be_dropped(rng):
    pts = rng.uniform(-1, 1, (4 * 6, 3)).astype(np.float32)
    pts[[3, 10, 11]] = np.nan
    msg = _realsense_cloud(pts, rng.integers(0, 256, (24, 3)), height=4)
    org = cloud_from_msg(msg)
    assert org.organised and org.points.shape == (4, 6, 3)
    assert np.isnan(org.points[0, 3, 0]) and np.isnan(org.points[1, 4, 2])
    flat = cloud_from_msg(msg, drop_nan=True)
    assert flat.points.shape == (21, 3) and flat.rgb.shape == (21, 3)
    assert np.all(np.isfinite(flat.points))


def test_round_trip_with_normals_and_organised_shape(rng):
    pts = rng.normal(size=(3, 5, 3))
    rgb = rng.uniform(0, 1, (3, 5, 3))
    nrm = rng.normal(size=(3, 5, 3))
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    back = cloud_from_msg(msg_from_cloud(pts, rgb, nrm, frame_id='base', stamp=12.25))
    np.testing.assert_allclose(back.points, pts, atol=1e-6)
    np.testing.assert_allclose(back.rgb, np.round(rgb * 255) / 255, atol=1e-12)
    np.testing.assert_allclose(back.normals, nrm, atol=1e-6)
    assert back.stamp == pytest.approx(12.25)


def test_empty_cloud_round_trips_to_empty_arrays():
    back = cloud_from_msg(msg_from_cloud(np.zeros((0, 3))))
    assert back.points.shape == (0, 3)


def test_surface_round_trip(rng):
    n = rng.normal(size=(40, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    s = Surface(points=rng.uniform(0, 0.1, (40, 3)), normals=n, colors=rng.uniform(0, 1, (40, 3)))
    back = surface_from_msg(surface_to_msg(s))
    np.testing.assert_allclose(back.points, s.points, atol=1e-7)
    np.testing.assert_allclose(back.normals, s.normals, atol=1e-6)
    assert back.frame == 'base'


def test_pack_unpack_rgb_inverse(rng):
    rgb = rng.integers(0, 256, (100, 3)) / 255.0
    np.testing.assert_allclose(unpack_rgb(pack_rgb(rgb)), rgb, atol=1e-12)


def test_missing_z_field_is_a_clear_error(rng):
    msg = _realsense_cloud(rng.uniform(size=(5, 3)).astype(np.float32), np.zeros((5, 3)))
    msg.fields = [f for f in msg.fields if f.name != 'z']
    with pytest.raises(InvalidInput, match="no 'z' field"):
        cloud_from_msg(msg)


def test_truncated_data_is_a_clear_error(rng):
    msg = _realsense_cloud(rng.uniform(size=(5, 3)).astype(np.float32), np.zeros((5, 3)))
    msg.data = bytes(msg.data)[:-7]
    with pytest.raises(InvalidInput, match='expected row_step x height'):
        cloud_from_msg(msg)


def test_field_beyond_point_step_is_a_clear_error(rng):
    msg = _realsense_cloud(rng.uniform(size=(5, 3)).astype(np.float32), np.zeros((5, 3)))
    msg.fields[3].offset = 40
    with pytest.raises(InvalidInput, match='point_step'):
        cloud_from_msg(msg)


def test_surface_without_normals_is_rejected(rng):
    with pytest.raises(InvalidInput, match='normal_x'):
        surface_from_msg(msg_from_cloud(rng.uniform(size=(4, 3))))


@pytest.mark.parametrize('count', [0, 3])
def test_coordinate_field_with_another_count_is_a_clear_error(rng, count):
    msg = msg_from_cloud(rng.uniform(size=(5, 3)))
    msg.fields[0].count = count   # x: a multi-count field is not read, so no x at all
    with pytest.raises(InvalidInput, match="'x' has count"):
        cloud_from_msg(msg)


def test_colour_and_normal_fields_with_another_count_are_not_read(rng):
    points = rng.uniform(size=(6, 3))
    normals = np.tile([0.0, 0.0, 1.0], (6, 1))
    msg = msg_from_cloud(points, rng.uniform(size=(6, 3)), normals)
    for field in msg.fields:
        if field.name in ('rgb', 'normal_y'):
            field.count = 2
    cloud = cloud_from_msg(msg)
    assert cloud.rgb is None and cloud.normals is None
    np.testing.assert_allclose(cloud.points, points, atol=1e-6)
