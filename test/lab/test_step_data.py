"""Step data end to end: the cell's step table -> CSV import -> learner -> pointforce diagnose.

The table (:mod:`pointforce_ros.lab.step_data`, seeded) has 64 pokes of 10 quasi-static
depth steps on the simulated lamb. Before issue 17 the learner refused every poke ("10 samples,
need at least 20"). Scoring is on held-out pokes only, against the noise-free force the
generator returns beside the table.
"""

import json

import numpy as np
import pytest

from pointforce_ros.bringup.cli import main as cli_main
from pointforce_ros.lab.step_data import make_step_table, score_step_table
from pointforce_ros.model.fit import fit_contact_model
from pointforce_ros.pokes.table import load_pokes

pytestmark = pytest.mark.slow


@pytest.fixture(scope='module')
def table(tmp_path_factory):
    return make_step_table(tmp_path_factory.mktemp('steps') / 'steps.csv', pokes=64,
                           per_poke=10, seed=3)


def test_generator_is_seeded_and_writes_the_import_format(table, tmp_path):
    again = make_step_table(tmp_path / 'again.csv', pokes=64, per_poke=10, seed=3)
    assert again['path'].read_text() == table['path'].read_text()
    records = load_pokes(table['path'])
    assert len(records) == 64 and all(len(r) == 10 for r in records)
    # the imported normal force is the generated one, in the same order
    np.testing.assert_allclose(np.array([r.normal_force() for r in records]), table['force'],
                               atol=1e-9)


def test_step_table_is_learned_and_scored_on_held_out_pokes(table):
    # the first 48 pokes through the CSV import and the learner, the other 16 held out and
    # scored against the generator's noise-free force at every step
    score = score_step_table(table, 48)
    assert score['learned'] + len(score['skipped']) == 48
    assert score['learned'] >= 45, score['skipped']
    assert np.isfinite(score['prequential'])
    assert score['heldout_rmse'] < 0.08 * score['peak'], score
    # no sign bias on the deepest step (the issue saw several tenths of a newton low there)
    assert abs(score['deepest_bias']) < 0.05 * score['peak']


def test_a_poke_that_cannot_be_used_is_reported_and_skipped(table):
    records = load_pokes(table['path'])[:12]
    short = records[3]
    keep = slice(0, 3)
    from pointforce_ros.types import PokeRecord
    records[3] = PokeRecord(poke_id=short.poke_id, point=short.point, normal=short.normal,
                            t=short.t[keep], t_controller=short.t_controller[keep],
                            tcp_pose=short.tcp_pose[keep], wrench=short.wrench[keep],
                            speed=short.speed)
    model = fit_contact_model(records, None)
    assert short.poke_id in model.meta['skipped']
    assert 'need at least 5' in model.meta['skipped'][short.poke_id]
    assert len(model.meta['pokes']) == 11


def test_pointforce_diagnose_scores_the_step_table(table, tmp_path, capsys):
    code = cli_main(['diagnose', str(table['path']), '--out', str(tmp_path / 'report'),
                     '--json'])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0
    assert set(summary['not_applicable']) == {'time_offset', 'viscoelastic'}
    rmse = summary['rmse']
    assert np.isfinite(rmse['model_before']) and rmse['model_before'] < 0.5
