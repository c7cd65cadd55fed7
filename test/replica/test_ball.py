"""Plate-on-ball replica (seed 002's setup): truth trials read, saved replica reproduces itself."""

from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput
from pointforce_ros.replica.contour import read_camera_views
from pointforce_ros.replica.data import load_pokes
from pointforce_ros.replica.evaluate import held_out_figures, truth_section
from pointforce_ros.replica.replica import load_replica
from pointforce_ros.replica.scene import Material, SceneConfig

DATA = Path(__file__).resolve().parents[1] / 'data' / 'replica'


def test_ball_trials_are_read_with_their_roles_and_ramp_and_hold_records():
    data = load_pokes(DATA / 'ball_plate.npz')
    train, held = data.split()
    assert (len(train), len(held)) == (3, 5) and data.ball_radius == pytest.approx(0.045)
    for poke in data.pokes:
        t, depth, force = poke.series
        assert depth.max() == pytest.approx(0.030) and poke.depth.max() == pytest.approx(0.030)
        holding = depth >= depth.max() - 1e-12
        # the Prony term: the force overshoots the relaxed curve and relaxes while holding
        assert force[holding][0] > 1.05 * poke.force[-1]
        assert force[holding][-25:].mean() < force[holding][:25].mean()
    speeds = sorted(p.speed for p in data.pokes)
    assert speeds[0] == pytest.approx(0.010) and speeds[-1] == pytest.approx(0.040)


def test_plate_is_a_pusher_and_unknown_pushers_are_refused():
    assert SceneConfig(pusher='plate').pusher == 'plate'
    with pytest.raises(InvalidInput, match='pusher'):
        SceneConfig(pusher='hammer')
    with pytest.raises(InvalidInput, match='onset'):
        SceneConfig(onset='never')


def test_saved_ball_replica_reloads_and_reproduces_its_reported_figures():
    loaded = load_replica(DATA / 'ball_replica')
    try:
        assert loaded.body_id >= 0 and loaded.pusher_id >= 0
        desc = loaded.description
        mesh = loaded.scene.mesh
    finally:
        loaded.scene.close()
    assert desc['config']['pusher'] == 'plate'
    again = held_out_figures(mesh, Material(**desc['material']), SceneConfig(**desc['config']),
                             load_pokes(DATA / 'ball_plate.npz'),
                             section=truth_section(DATA / 'ball_plate.npz'),
                             camera=read_camera_views(DATA / 'ball_plate_camera.npz'))
    for key, value in desc['figures'].items():
        if isinstance(value, float):
            assert again[key] == pytest.approx(value, rel=1e-3, abs=1e-6), key
    assert np.isfinite(again['force_time_pct']) and again['at_max_pct'] >= 0
    # the section is compared at the truth's compression, and the ball stays upright
    assert again['section_compression_m'] == pytest.approx(0.030, abs=0.001)
    assert again['section_error_pct'] < 3.0
    assert again['camera_error_pct'] < 3.0 and again['camera_bins'] > 20  # the camera's view
