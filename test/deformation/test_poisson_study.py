"""The Poisson-ratio study's data handling (the study itself is a CLI run on the fixtures)."""

import shutil

import numpy as np
import pytest

from pointforce_ros.deformation.poisson_study import FIXTURES, pokes_of, study, table
from pointforce_ros.errors import DataError


def test_missing_fixtures_name_the_script_that_makes_them(tmp_path):
    with pytest.raises(DataError, match='make_deformation_fixtures'):
        study(folder=tmp_path)
    for name in ('rest_foam_block.npz', 'push_foam_block_0.npz'):
        shutil.copy(FIXTURES / name, tmp_path / name)
    with pytest.raises(DataError, match='make_side_pushes'):
        study(folder=tmp_path)


def test_a_side_push_state_is_read_at_the_asked_depth():
    with np.load(FIXTURES / 'side_foam_block_0.npz') as z:
        push = dict(z)
    poke = pokes_of(push, 0.005)
    np.testing.assert_allclose(poke.force, push['force'][1])
    assert len(poke.cloud) == push['cloud_start'][2] - push['cloud_start'][1]
    # the push is horizontal, into the -x face
    assert poke.force[0] > 0.9 * np.linalg.norm(poke.force)


def test_table_lists_every_row():
    row = {'set': 'top + side', 'depth_mm': 3.0, 'young': 5.15e4, 'young_error_pct': 2.9,
           'poisson': 0.303, 'poisson_error': 0.003, 'poisson_interval': [0.283, 0.334],
           'residual_change_pct': 3.3, 'heldout_force_error_pct_median': 6.5,
           'heldout_force_error_pct_max': 11.7}
    text = table({'rows': [row]})
    assert ('| top + side | 3 | 51.5 (+2.9 %) | 0.303 (+0.003) | 0.283-0.334 | 3.3 % | '
            '6.5 / 11.7 % |') in text
