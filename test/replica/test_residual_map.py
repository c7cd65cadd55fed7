"""The residual map of a replica: its numbers agree with the figures and see a wrong stiffness."""

from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.replica.calibrate import evaluate, force_time_errors
from pointforce_ros.replica.data import load_pokes
from pointforce_ros.replica.mesh import read_vtk
from pointforce_ros.replica.replica import read_description
from pointforce_ros.replica.residual_map import plot_residual_map, residual_map
from pointforce_ros.replica.scene import Material, SceneConfig

DATA = Path(__file__).resolve().parents[1] / 'data' / 'replica'


def test_residual_map_agrees_with_the_figures_and_sees_a_stiffer_body(tmp_path):
    desc = read_description(DATA / 'ball_replica')
    mesh = read_vtk(DATA / 'ball_replica' / 'body.vtk', desc['mesh']['resolution_m'])
    material, config = Material(**desc['material']), SceneConfig(**desc['config'])
    _, held = load_pokes(DATA / 'ball_plate.npz').split()
    fastest = [max(held, key=lambda p: p.speed)]  # the shortest ramp-and-hold simulation
    result = residual_map(mesh, material, config, fastest)
    numbers = result['numbers']
    site = numbers['by_site']['pokes'][0]
    err = evaluate(mesh, material, fastest, config)[0]
    assert abs(site['at_max_signed_pct']) == pytest.approx(100 * err.at_max, rel=1e-6)
    assert site['curve_rms_pct'] == pytest.approx(100 * err.curve, rel=1e-6)
    # the phases split the force-time record: their RMS recombine into the whole one
    row, (t, _, force) = numbers['by_time']['pokes'][0], fastest[0].series
    holding = result['curves']['pokes'][0]['holding']
    whole = np.sqrt((np.count_nonzero(~holding) * row['push_rms_pct'] ** 2
                     + np.count_nonzero(holding) * row['hold_rms_pct'] ** 2) / len(t))
    rms = force_time_errors(mesh, material, fastest, config)[0]
    assert whole == pytest.approx(100 * rms / force.max(), rel=1e-6)
    # a body 30 % stiffer shows as a positive residual, largest where the force is
    # (the 15 mm test mesh is itself ~8 % stiff at depth with the 10 mm mesh's material)
    stiff = residual_map(mesh, material.scaled(1.3), config,
                         fastest)['numbers']['by_depth']['mean_signed_pct']
    calibrated = numbers['by_depth']['mean_signed_pct']
    assert stiff[2] - calibrated[2] > 12.0 and stiff[2] > stiff[0] + 5.0
    plot_residual_map(result, tmp_path / 'map.png', 'test')
    assert (tmp_path / 'map.png').read_bytes()[:4] == b'\x89PNG'
