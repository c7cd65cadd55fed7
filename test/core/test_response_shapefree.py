"""Shape-free candidate model: invariants, and where it beats the power law (softening)."""

import numpy as np
import pytest

from pointforce_ros.lab.synthetic_contact import grid_surface
from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.common import curve_features
from pointforce_ros.lab.evaluate import learning_curve
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.response.shapefree import curve_knots, KNOTS, ShapeFreeGpModel


def _softening_world(count=14, seed=5):
    """Curves that stiffen first and then soften (a dome's shell), stiffness varying in x."""
    rng = np.random.default_rng(seed)
    surface = grid_surface(0.06, 0.04, 0.002)
    idx = rng.choice(len(surface), count, replace=False)
    curves = []
    for k, i in enumerate(idx):
        p = surface.points[i]
        onset = -0.002 + rng.normal(0.0, 0.0002)
        d = np.linspace(-0.004, 0.010, 1400)
        s = np.maximum(d - onset, 0.0)
        amp = 6.0 * (1.0 + 0.1 * np.sin(p[0] / 0.03 * np.pi))
        f = amp * np.tanh((s / 0.004) ** 1.5) + rng.normal(0.0, 0.03, len(d))
        curves.append(PokeCurve(poke_id=f'poke-{k:06d}', point=p, normal=surface.normals[i],
                                d=d, f=f, onset_d=onset, t=np.arange(len(d)) / 250.0))
    return surface, curves


def test_prediction_is_zero_before_the_onset_and_monotone_in_depth():
    surface, curves = _softening_world()
    model = ShapeFreeGpModel().fit(curves[:8], surface)
    x = curve_features(curves[8:10], surface)
    d = np.linspace(-0.006, 0.03, 400)
    for row in x:
        f = model.predict(np.repeat(row[None], len(d), 0), d)
        assert np.all(f[d < -0.004] == 0.0)
        assert np.all(np.diff(f) >= -1e-12)
        assert f[-1] > 0.0


def test_beats_the_power_law_on_softening_curves_held_out():
    surface, curves = _softening_world()
    rows = learning_curve(curves, surface, {'power_law': ContactGpModel,
                                            'shape_free': ShapeFreeGpModel},
                          sizes=(5,), repeats=3, seed=2)
    med = {r['model']: r['median'] for r in rows}
    assert med['shape_free'] < 0.6 * med['power_law'], med


def test_knots_follow_the_curve_and_errors_are_clear():
    surface, curves = _softening_world(count=2)
    c = curves[0]
    y = curve_knots(c)
    assert y.shape == KNOTS.shape and np.all(np.diff(y) >= -1e-12)
    s_mid = 0.004
    truth = np.interp(s_mid, c.d - c.onset_d, c.f)
    assert np.exp(np.interp(s_mid, KNOTS, y)) - 0.05 == pytest.approx(truth, abs=0.15)
    short = PokeCurve(poke_id='short', point=c.point, normal=c.normal, d=c.d[:3], f=c.f[:3],
                      onset_d=0.0, t=c.t[:3])
    with pytest.raises(InvalidInput, match='fewer than 3'):
        curve_knots(short)
    with pytest.raises(ModelNotReady):
        ShapeFreeGpModel().predict(np.zeros((1, 9)), [0.0])


def test_a_curve_too_short_past_its_onset_is_skipped_not_fatal():
    surface, curves = _softening_world(count=9)
    c = curves[4]
    s = c.d - c.onset_d
    cut = np.flatnonzero(s > 0)[1] + 1          # two samples past the onset
    short = PokeCurve(poke_id=c.poke_id, point=c.point, normal=c.normal, d=c.d[:cut],
                      f=c.f[:cut], onset_d=c.onset_d, t=c.t[:cut])
    pool = curves[:4] + [short] + curves[5:]
    model = ShapeFreeGpModel().fit(pool, surface)
    assert list(model.skipped) == [c.poke_id] and 'past the contact onset' in \
        model.skipped[c.poke_id]
    assert c.poke_id not in model.poke_ids and len(model.poke_ids) == 8
    # and a learning curve over the pool runs to the end
    rows = learning_curve(pool, surface, {'shape_free': ShapeFreeGpModel}, sizes=(3, 5),
                          repeats=3, seed=1)
    assert [r['size'] for r in rows] == [3, 5]
    assert all(np.isfinite(r['median']) for r in rows)


def test_step_data_curves_of_ten_samples_are_learned():
    surface, curves = _softening_world(count=12, seed=7)
    steps = []
    for c in curves:
        take = np.round(np.linspace(0, len(c.d) - 1, 10)).astype(int)
        steps.append(PokeCurve(poke_id=c.poke_id, point=c.point, normal=c.normal, d=c.d[take],
                               f=c.f[take], onset_d=c.onset_d, t=c.t[take]))
    model = ShapeFreeGpModel().fit(steps[:9], surface)
    assert not model.skipped
    x = curve_features(curves[9:], surface)
    err = np.concatenate([model.predict(row[None].repeat(len(c.d), 0), c.d) - c.f
                          for row, c in zip(x, curves[9:])])
    assert np.sqrt(np.mean(err ** 2)) < 0.1 * 6.0
