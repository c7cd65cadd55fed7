"""The section under load against the camera's: extraction, depth bias, and the gap measure."""

from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.replica.contour import (camera_section, camera_section_error,
                                            depth_bias_from_rest, read_camera_views,
                                            remove_depth_bias)
from pointforce_ros.replica.evaluate import camera_views_file

DATA = Path(__file__).resolve().parents[1] / 'data' / 'replica'
CENTRE = np.array([0.0, 0.03])


def _squashed(a=0.048, b=0.030, n=400):
    """Outline (x, z) of a squashed ball: an ellipse about CENTRE, half-width a, half-height b."""
    t = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return np.column_stack([a * np.cos(t), CENTRE[1] + b * np.sin(t)])


def _camera_cloud(outline, noise, seed, side_view=True):
    """Points on the body of revolution of ``outline`` near y = 0, with seeded range noise."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(-np.pi, np.pi, 4000)
    r = np.interp(t, np.arctan2(outline[:, 1] - CENTRE[1], outline[:, 0]),
                  np.hypot(outline[:, 0], outline[:, 1] - CENTRE[1]), period=2 * np.pi)
    x, z = r * np.cos(t), CENTRE[1] + r * np.sin(t)
    phi = rng.uniform(-0.2, 0.2, len(t))  # around the axis: off the section plane
    pts = np.column_stack([x * np.cos(phi), np.abs(x) * np.sin(phi), z])
    if side_view:  # two side cameras see the outer half of each side, not top and bottom
        pts = pts[np.abs(np.sin(t)) < 0.8]
    return pts + rng.normal(0.0, noise, (len(pts), 1)) * [1.0, 0.0, 0.0]


def test_camera_section_sees_the_true_outline_and_not_a_scaled_one():
    truth = _squashed()
    section = camera_section(_camera_cloud(truth, 0.0007, seed=1), (0.0, 0.0), band=0.003)
    assert np.all(np.abs(section[:, 0]) > 0.015)  # only the sides, as the cameras see them
    true = camera_section_error(section, truth, CENTRE)
    wider = camera_section_error(section, (truth - CENTRE) * 1.03 + CENTRE, CENTRE)
    assert true['error_pct'] < 0.4 and abs(true['bias_m']) < 2e-4
    np.testing.assert_allclose(true['width_m'], 0.096, rtol=0.01)
    # 3 % wider: the gap is 3 % of the radius where the camera sees, ~1.5 % of the width
    assert wider['error_pct'] > true['error_pct'] + 1.0
    assert wider['bias_m'] > 0.0011
    # diameters by height are noisier (a few points per side and level) but still tell
    assert true['diameter_rms_pct'] < 1.2 < wider['diameter_rms_pct'] - true['diameter_rms_pct']
    with pytest.raises(InvalidInput, match='angle bins'):
        camera_section_error(section[:4], truth, CENTRE)


def test_depth_bias_is_found_on_the_rest_ball_and_removed():
    rng = np.random.default_rng(3)
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]  # optical z -> +x
    pose[:3, 3] = [-0.35, 0.0, 0.045]
    centre, radius = np.array([0.0, 0.0, 0.045]), 0.045
    # the visible hemisphere's points, read 2 mm too far along the optical axis
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    true = centre + radius * d[d[:, 0] < -0.3]
    rel = true - pose[:3, 3]
    cos = (rel / np.linalg.norm(rel, axis=1, keepdims=True)) @ pose[:3, 2]
    seen = true + rel / np.linalg.norm(rel, axis=1, keepdims=True) * (0.002 / cos)[:, None]
    bias = depth_bias_from_rest(seen, pose, centre, radius)
    np.testing.assert_allclose(bias, 0.002, atol=2e-5)
    np.testing.assert_allclose(remove_depth_bias(seen, pose, bias), true, atol=5e-5)
    with pytest.raises(InvalidInput, match='rest ball'):
        depth_bias_from_rest(seen + [0.0, 0.5, 0.0], pose, centre, radius)


@pytest.mark.parametrize('name', ['ball_plate', 'ball_core'])
def test_the_cell_camera_views_of_the_truth_give_its_section_within_the_floor(name):
    views = read_camera_views(DATA / f'{name}_camera.npz')
    assert camera_views_file(DATA / f'{name}.npz') == DATA / f'{name}_camera.npz'
    with np.load(DATA / f'{name}.npz') as z:
        truth = np.asarray(z['section_xz'], float)
    radius = float(views['radius'])
    biases = [depth_bias_from_rest(r, p, [0.0, 0.0, radius], radius)
              for r, p in zip(views['rest'], views['pose'])]
    # the scenario reads 2 mm too far; the rest ball finds it (the FEM's facets: ~0.1 mm)
    np.testing.assert_allclose(biases, views['depth_bias'], atol=4e-4)
    pts = [np.concatenate(views['loaded'])]
    pts.append(np.concatenate([remove_depth_bias(q, p, b)
                               for q, p, b in zip(views['loaded'], views['pose'], biases)]))
    raw, fixed = (camera_section_error(camera_section(p, (0.0, 0.0)), truth, CENTRE)
                  for p in pts)
    assert fixed['error_pct'] < 0.6 < raw['error_pct']  # the bias is most of the raw gap
    wider = camera_section_error(camera_section(pts[1], (0.0, 0.0)),
                                 (truth - CENTRE) * 1.03 + CENTRE, CENTRE)
    assert wider['error_pct'] > fixed['error_pct'] + 0.8


def test_unreadable_camera_views_are_a_data_error(tmp_path):
    (tmp_path / 'v.npz').write_text('not a zip')
    with pytest.raises(DataError, match='unreadable camera views'):
        read_camera_views(tmp_path / 'v.npz')
