"""The model RMSE (white noise averaged out), Prony viscoelasticity and halving at realistic noise.

The sample RMSE of a held-out residual includes the F/T white noise; the model RMSE averages
the residual over 0.25 s blocks of one phase of one poke (``effects.model.model_blocks``). The
realistic-noise sets are the closing table's (``test/data/diagnose/effect_table.py``): the
analytic object, 16 pokes, the cell's scenario effect plus 0.03 N F/T noise per sample.
"""

import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.diagnose import diagnose
from pointforce_ros.diagnose.batch import make_batch
from pointforce_ros.effects.library import check_params, PRONY_TAUS, prony_terms
from pointforce_ros.diagnose.model import block_sse, model_blocks
from pointforce_ros.errors import InvalidInput

HERE = Path(__file__).resolve().parents[1] / 'data' / 'diagnose'


def _load(name, file):
    spec = importlib.util.spec_from_file_location(name, HERE / file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


datasets = _load('diagnose_datasets_model_rmse', 'datasets.py')
table = _load('diagnose_effect_table_model_rmse', 'effect_table.py')


@functools.lru_cache(maxsize=None)
def realistic(name):
    obj, common = table.cell_object('analytic')
    records = table.records_for(obj, common, name, 16, 1)
    return diagnose(records, seed=0, bootstrap=3, log=lambda line: None)


def _model_rmse(batch, resid, blocks):
    sse, count = block_sse(batch, resid, blocks)
    return float(np.sqrt(sse.sum() / count.sum()))


def test_model_rmse_keeps_structure_and_divides_white_noise_by_the_block():
    batch, _ = make_batch(datasets.make('clean'), max_rate=50.0)
    blocks = model_blocks(batch)
    covered = blocks >= 0
    assert covered.mean() > 0.9
    # a block holds one poke and one phase: its samples are consecutive
    for b in np.unique(blocks[covered])[:50]:
        idx = np.flatnonzero(blocks == b)
        assert np.all(np.diff(idx) == 1) and len(set(batch.seg[idx])) == 1
    size = int(round(0.25 / np.median(batch.dt)))
    # a structural residual slower than a block is kept exactly
    const = np.tile([0.03, -0.04, 0.0], (batch.n_samples, 1))
    assert _model_rmse(batch, const, blocks) == pytest.approx(0.05, rel=1e-12)
    # opposite signs on loading and unloading (a lag or hysteresis) do not cancel
    sign = np.sign(np.gradient(batch.d, batch.tv))[:, None] * np.array([[0.0, 0.0, 0.02]])
    moving = covered & (np.abs(np.gradient(batch.d, batch.tv)) > 1e-4)
    assert _model_rmse(batch, np.where(moving[:, None], sign, 0.0), np.where(
        moving, blocks, -1)) == pytest.approx(0.02, rel=1e-9)
    # white noise: the variance of a block mean is sigma^2 / n (n >= size samples per block)
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 0.03, (batch.n_samples, 3))
    sample = float(np.sqrt(np.mean(np.sum(noise ** 2, axis=1))))
    model = _model_rmse(batch, noise, blocks)
    assert sample == pytest.approx(0.03 * np.sqrt(3), rel=0.05)
    assert 0.6 / np.sqrt(size) < model / sample < 1.1 / np.sqrt(size)
    with pytest.raises(InvalidInput):
        model_blocks(batch, seconds=0.0)


def test_small_drift_halves_the_model_rmse_though_noise_holds_the_sample_rmse():
    report = realistic('ft_drift')
    assert report.accepted_names == ['ft_drift']
    # 0.03 N per sample is most of the error before: the sample RMSE cannot halve
    assert report.rmse_after > 0.5 * report.rmse_before
    assert report.halved and report.model_rmse_after <= 0.5 * report.model_rmse_before
    # after the fit the model RMSE is the noise's share left in a block mean
    assert report.model_rmse_after < 0.5 * report.noise_rms


def test_two_term_relaxation_total_fraction_is_recovered_by_the_prony_series():
    # the cell relaxes with g = 0.15 (tau 0.5 s) + 0.10 (tau 5 s): a one-term fit missed the
    # total 0.25 by 27-29 %
    report = realistic('viscoelastic')
    assert report.accepted_names == ['viscoelastic']
    (accepted,) = report.accepted
    assert accepted.params['g'] == pytest.approx(0.25, rel=0.2)
    assert 0 < accepted.std['g'] < 0.1 and accepted.low['g'] <= accepted.high['g']
    assert report.halved
    g, tau = prony_terms(accepted.params)
    assert np.all(g >= 0) and g.sum() == pytest.approx(accepted.params['g'])
    np.testing.assert_allclose(tau, PRONY_TAUS)


def test_prony_parameters_are_checked_and_the_total_is_derived():
    # issue 20: the grid spans 0.03-30 s (seven terms); a five-term series written with the
    # earlier 0.1-10 s grid still loads when it carries its relaxation times
    params = {'e1': 0.0, 'e2': 0.5, 'e3': 0.0, 'e4': 0.25, 'e5': 0.0, 'e6': 0.0, 'e7': 0.0,
              'g': 99.0}
    checked = check_params('viscoelastic', params)
    assert checked['g'] == pytest.approx(0.75 / 1.75)     # recomputed, not taken
    assert checked['tau2'] == 0.1
    g, tau = prony_terms(checked)
    np.testing.assert_allclose(g, [0.0, 0.5 / 1.75, 0.0, 0.25 / 1.75, 0.0, 0.0, 0.0])
    old = {f'e{i + 1}': v for i, v in enumerate([0.0, 0.5, 0.0, 0.25, 0.0])}
    old.update({f'tau{i + 1}': v for i, v in enumerate([0.1, 0.3, 1.0, 3.0, 10.0])})
    g, tau = prony_terms(check_params('viscoelastic', old))
    np.testing.assert_allclose(tau, [0.1, 0.3, 1.0, 3.0, 10.0])
    np.testing.assert_allclose(g, [0.0, 0.5 / 1.75, 0.0, 0.25 / 1.75, 0.0])
    with pytest.raises(InvalidInput, match='>= 0'):
        check_params('viscoelastic', {**params, 'e1': -0.1})
    with pytest.raises(InvalidInput, match='missing'):
        check_params('viscoelastic', {'e1': 0.1})
    legacy = check_params('viscoelastic', {'g': 0.3, 'tau': 2.0})
    assert [list(v) for v in prony_terms(legacy)] == [[0.3], [2.0]]
    with pytest.raises(InvalidInput, match='fraction'):
        check_params('viscoelastic', {'g': 1.2, 'tau': 2.0})
