"""Replica files: written, reloaded with one call, and reproducing their own figures; bad input."""

import json
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.replica.calibrate import evaluate, summary
from pointforce_ros.replica.data import load_pokes, MeasuredPoke
from pointforce_ros.replica.mesh import box_tet_mesh
from pointforce_ros.replica.replica import load_replica, write_replica
from pointforce_ros.replica.scene import Material, SceneConfig

PUSHES = Path(__file__).resolve().parents[1] / 'data' / 'deformation'


def _pokes():
    depth = np.linspace(0.0002, 0.004, 40)
    return [MeasuredPoke(f'poke-{k}', xy, depth, 300.0 * depth * (1 + 150 * depth),
                         depth / 0.002)
            for k, xy in enumerate(([0.49, -0.005], [0.51, 0.008]))]


def test_reloaded_replica_reproduces_its_reported_figures(tmp_path):
    mesh = box_tet_mesh([0.09, 0.07, 0.04], [0.5, 0.0], 0.015)
    material = Material.from_young(7e4, 0.35, 0.03)
    config = SceneConfig()
    pokes = _pokes()
    figures = summary(evaluate(mesh, material, pokes, config))
    write_replica(tmp_path / 'rep', mesh, material, config, figures=figures)
    loaded = load_replica(tmp_path / 'rep')
    try:
        assert loaded.body_id >= 0 and loaded.pusher_id >= 0 and loaded.table_id >= 0
        desc = loaded.description
        assert desc['material'] == pytest.approx({'mu': material.mu, 'lam': material.lam,
                                                  'damping': 0.03})
        assert (tmp_path / 'rep' / 'body.vtk').read_text().count('\n10\n') >= 1
        reloaded_mesh = loaded.scene.mesh
    finally:
        loaded.scene.close()
    again = summary(evaluate(reloaded_mesh, Material(**desc['material']),
                             pokes, SceneConfig(**desc['config'])))
    for key, value in desc['figures'].items():
        assert again[key] == pytest.approx(value, rel=1e-3, abs=1e-6), key
    assert figures['curve_pct'] > 0  # a synthetic law the replica does not reproduce exactly


def test_bad_replica_dir_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match='not a replica directory'):
        load_replica(tmp_path)
    (tmp_path / 'replica.json').write_text(json.dumps({'format': 'other/0'}))
    with pytest.raises(DataError, match='format'):
        load_replica(tmp_path)


def test_bad_pokes_get_one_line_errors(tmp_path):
    with pytest.raises(DataError, match='no such'):
        load_pokes(tmp_path / 'missing')
    with pytest.raises(DataError, match='not a poke store'):
        load_pokes(tmp_path)
    np.savez(tmp_path / 'nosurf.npz', curve_ids=np.array(['a']))
    with pytest.raises(DataError, match='without a surface'):
        load_pokes(tmp_path / 'nosurf.npz')
    np.savez(tmp_path / 'nopokes.npz', surface_points=np.ones((20, 3)),
             curve_ids=np.array([], dtype='<U4'), curve_offsets=np.array([0]))
    with pytest.raises(InvalidInput, match='no pokes'):
        load_pokes(tmp_path / 'nopokes.npz')
    (tmp_path / 'junk.npz').write_text('not a zip')
    with pytest.raises(DataError, match='unreadable'):
        load_pokes(tmp_path / 'junk.npz')
    store = tmp_path / 'store'
    store.mkdir()
    (store / 'index.json').write_text(json.dumps({'pokes': []}))
    with pytest.raises(InvalidInput, match='no pokes'):
        load_pokes(store)


def test_static_pushes_of_the_deformation_fixtures_keep_their_roles():
    data = load_pokes(str(PUSHES / 'push_foam_block_*.npz'))
    train, held = data.split()
    assert len(train) == 3 and len(held) == 3
    assert {p.poke_id for p in held} == set(data.held_out_ids)
    for poke in data.pokes:
        assert np.all(np.diff(poke.force) > 0) and poke.force[0] > 0.1  # pushed back, N
    assert abs(data.surface_points[:, 2].max() - 0.04) < 0.002
    with pytest.raises(InvalidInput, match='no push files'):
        load_pokes(str(PUSHES / 'push_nothing_*.npz'))


def test_the_command_answers_bad_input_with_one_line(tmp_path, capsys):
    from pointforce_ros.bringup.cli import main  # the ``pointforce`` command itself
    np.savez(tmp_path / 'nosurf.npz', curve_ids=np.array(['a']))
    (tmp_path / 'junk.npz').write_text('not a zip')
    store = tmp_path / 'store'
    store.mkdir()
    (store / 'index.json').write_text(json.dumps({'pokes': []}))
    cases = {'no pokes': store, 'without a surface': tmp_path / 'nosurf.npz',
             'unreadable': tmp_path / 'junk.npz', 'no such': tmp_path / 'missing'}
    for expected, data in cases.items():
        rc = main(['replica', '--engine', 'pybullet', '--data', str(data),
                   '--out', str(tmp_path / 'rep')])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and expected in err, (expected, err)
        assert len(err.splitlines()) == 1 and err.startswith('pointforce replica: error:')
    assert not (tmp_path / 'rep').exists()  # nothing written on bad input


def test_load_replica_is_one_import_away_and_the_command_does_not_load_pybullet():
    import subprocess
    import sys
    code = ('import sys; import pointforce_ros.replica.cli; '
            'assert "pybullet" not in sys.modules; '
            'from pointforce_ros.replica import load_replica, LoadedReplica; '
            'assert callable(load_replica) and "pybullet" in sys.modules')
    assert subprocess.run([sys.executable, '-c', code]).returncode == 0
    import pointforce_ros.replica as package
    with pytest.raises(AttributeError):
        package.not_there
