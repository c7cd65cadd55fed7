"""Check that the service's 90 % wrench intervals cover held-out truth (issue 17).

For each object with a probe fixture (``data/figures/probes_<name>.npz``: FEM full-solve line and
cylinder trials) the point model is trained on ``n_train`` random pokes of its poke fixture, and
each trial is scored with the shape function calibrated on the object's *other* trials (leave one
trial out, as figure 2) by :func:`~pointforce_ros.contact.identify.calibrate_shape`: ``(c, L)``,
its covariance widened by the spread of ``c`` between those trials, the share of the force
missed on a trial the fit has not seen (each of the *other* trials predicted from the rest in
turn) and the lateral share: the sources the learner stores in a model and the contact service
turns into ``wrench_std``. The truth of the trial never enters its interval.
``sources='fit_only'`` takes the joint fit's own covariance and residual share instead (what the
demo stored before issue 17's second pass), for a before/after comparison.

``python -m pointforce_ros.lab.coverage --out DIR`` prints one line per object and the pooled
coverage, and writes ``coverage.json`` and ``coverage.png`` (normalised errors ``err / std``
against the nominal normal).
"""

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Callable, Dict, Mapping, Optional, Sequence

import numpy as np

from pointforce_ros.contact.identify import calibrate_shape, decay_grid, shape_fit_covariance
from pointforce_ros.contact.lcp import NEARS
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.contact.uncertainty import uncertainty_sources, wrench_uncertainty, Z90
from pointforce_ros.errors import InvalidInput, PointforceError
from pointforce_ros.lab.figures import (bake_depths, DATA_DIR, DEFAULT_C, load_poke_fixture,
                                        load_probe_fixture, OBJECTS, PROBE_TRAIN_POKES,
                                        trial_poses)
from pointforce_ros.model.files import ContactModel
from pointforce_ros.pokes.curves import learned_depth, PokeCurve
from pointforce_ros.response.baked import EXTRAPOLATION_KAPPA
from pointforce_ros.response.ours import product_model
from pointforce_ros.types import Surface


def cut_curve(curve: PokeCurve, depth: float) -> Optional[PokeCurve]:
    """Return ``curve`` without its samples deeper than ``depth`` (m); ``None``: under 20 left."""
    keep = np.asarray(curve.d) <= depth
    if int(keep.sum()) < 20:
        return None
    return dataclasses.replace(curve, d=np.asarray(curve.d)[keep],
                               f=np.asarray(curve.f)[keep], t=np.asarray(curve.t)[keep])


def _push(trial: Mapping) -> tuple:
    return trial['mesh'], trial_poses(trial), trial['direction'], trial['force']


def probe_coverage(curves: Sequence[PokeCurve], surface: Surface, trials: Sequence[Mapping],
                   n_train: int = PROBE_TRAIN_POKES, seed: int = 0,
                   say: Callable[[str], None] = print, sources: str = 'calibrated',
                   nears: Sequence[str] = NEARS, cut: Optional[float] = None,
                   kappa: float = EXTRAPOLATION_KAPPA) -> Dict:
    """Score the 90 % intervals of every probe-trial step of one object (module docstring).

    Args:
        curves: the object's poke curves; ``n_train`` of them, drawn with ``seed``, train the
            point model.
        surface: the scanned surface the model is baked on.
        trials: probe trials (:func:`~pointforce_ros.lab.figures.load_probe_fixture`), >= 2.
        n_train: training pokes.
        seed: draw of the training pokes.
        say: progress lines.
        sources: ``'calibrated'`` (the default: what
            :meth:`~pointforce_ros.contact.identify.ShapeCalibration.sources` gives) or
            ``'fit_only'`` (the joint fit's own covariance and relative residual).
        nears: the near fields the other trials choose from, as figure 2's
            (:func:`~pointforce_ros.contact.identify.choose_near`).
        cut: metres; the training pokes' samples deeper than this are dropped (pokes that
            stopped there: the trials press past them), a poke left with fewer than 20
            samples is not trained on; ``None``: whole pokes.
        kappa: growth of the response's std past the training pokes' deepest displacement
            (:meth:`~pointforce_ros.response.baked.BakedResponse.with_extrapolation`; 0: the
            model's own spread alone, as before it).

    Returns:
        ``{'normal': (S,) normalised error err/std of the force along the push, 'force': (S, 3)
        of each force component, 'torque': (S, 3) of each torque component (about the trial's
        torque centre), 'pred', 'std', 'true': (S, 3) N, 'kinds': (S,) trial kind,
        'relative_std': (S,) the relative share each step's interval used}`` over the ``S``
        steps of all trials.

    Raises:
        InvalidInput: fewer than 2 trials or fewer than ``n_train`` curves, or an unknown
            ``sources``.

    """
    if sources not in ('calibrated', 'fit_only'):
        raise InvalidInput(f"sources: 'calibrated' or 'fit_only', got {sources!r}")
    trials = list(trials)
    if len(trials) < 2:
        raise InvalidInput('probe_coverage: need >= 2 trials (the others calibrate (c, L))')
    if len(curves) < n_train:
        raise InvalidInput(f'probe_coverage: need >= {n_train} curves, got {len(curves)}')
    rng = np.random.default_rng([int(seed), 17])
    train = [curves[i] for i in rng.choice(len(curves), size=n_train, replace=False)]
    if cut is not None:
        train = [c for c in (cut_curve(c, cut) for c in train) if c is not None]
    baked = product_model().fit(train, surface).bake(surface, bake_depths(curves)) \
        .with_extrapolation(learned_depth(train), kappa)
    nominal = ContactSimulator(surface, baked, DEFAULT_C)
    rows = {'normal': [], 'force': [], 'torque': [], 'pred': [], 'std': [], 'true': [],
            'kinds': [], 'relative_std': []}
    decays = decay_grid(surface)        # the tail within DECAY_CAP thicknesses of the object
    for j, trial in enumerate(trials):
        others = [_push(t) for i, t in enumerate(trials) if i != j]
        try:
            cal = calibrate_shape(nominal, others, decays=decays, nears=nears)
        except (PointforceError, ValueError) as exc:
            say(f'[coverage]   trial {j}: (c, L) not identified from the others ({exc})')
            continue
        fit = cal.fit
        meta = cal.sources() if sources == 'calibrated' else uncertainty_sources(
            shape_cov=shape_fit_covariance(nominal.with_shape_constant(nominal.c,
                                                                       near=cal.near),
                                           others, fit),
            relative_std=cal.in_sample_std, lateral_std=cal.lateral_std)
        model = ContactModel(surface=surface, response=baked, shape_constant=fit.c, version=1,
                             shape_decay=fit.decay, meta=meta, shape_near=cal.near)
        out = wrench_uncertainty(model, trial['mesh'], trial_poses(trial), trial['direction'],
                                 trial['torque_centre'])
        pred, std = out.wrench[:, :3], np.maximum(out.std[:, :3], 1e-12)
        true = np.asarray(trial['force'], dtype=float)
        rows['torque'].append((out.wrench[:, 3:] - np.asarray(trial['torque'], dtype=float))
                              / np.maximum(out.std[:, 3:], 1e-12))
        a = -np.asarray(trial['direction'], dtype=float)
        a_std = np.sqrt(np.sum((std * a) ** 2, axis=1))   # components' std along the push
        rows['normal'].append(((pred - true) @ a) / np.maximum(a_std, 1e-12))
        rows['force'].append((pred - true) / std)
        rows['pred'].append(pred)
        rows['std'].append(std)
        rows['true'].append(true)
        rows['kinds'] += [trial['kind']] * len(true)
        rows['relative_std'] += [meta.get('relative_std', 0.0)] * len(true)
        say(f'[coverage]   trial {j} ({trial["kind"]}): c {1e3 * fit.c:.2f} mm, L '
            + (f'{1e3 * fit.decay:.0f} mm' if np.isfinite(fit.decay) else 'none')
            + f', {cal.near} near field, relative std '
            f'{meta.get("relative_std", 0.0):.0%} (in-sample {cal.in_sample_std:.0%}); covered '
            f'{np.mean(np.abs(rows["normal"][-1]) <= Z90):.0%} of {len(true)} steps')
    if not rows['normal']:
        raise InvalidInput('probe_coverage: no trial could be calibrated from the others')
    return {'normal': np.concatenate(rows['normal']), 'force': np.vstack(rows['force']),
            'torque': np.vstack(rows['torque']), 'pred': np.vstack(rows['pred']),
            'std': np.vstack(rows['std']), 'true': np.vstack(rows['true']),
            'kinds': np.array(rows['kinds']), 'relative_std': np.array(rows['relative_std'])}


def summary(result: Mapping) -> Dict:
    """Coverage of the nominal 90 % intervals and their mean relative width, of one result."""
    normal = np.asarray(result['normal'])
    pred, std = np.asarray(result['pred']), np.asarray(result['std'])
    peak = np.linalg.norm(result['true'], axis=1)
    return {'steps': int(len(normal)),
            'coverage_normal': float(np.mean(np.abs(normal) <= Z90)),
            'coverage_force': float(np.mean(np.abs(result['force']) <= Z90)),
            'coverage_torque': float(np.mean(np.abs(result['torque']) <= Z90))
            if 'torque' in result else float('nan'),
            'below': int(np.sum(normal < 0)), 'above': int(np.sum(normal > 0)),
            'width_over_force': float(np.median(2 * Z90 * np.linalg.norm(std, axis=1)
                                                / np.maximum(peak, 1e-9))),
            'mean_force': float(np.mean(np.linalg.norm(pred, axis=1))),
            'relative_std': float(np.median(result['relative_std']))
            if 'relative_std' in result else float('nan')}


def _plot(results: Mapping[str, Mapping], path: Path) -> None:
    import matplotlib  # optional plotting dependency: only the CLI draws
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    bins = np.linspace(-4, 4, 33)
    for name, result in results.items():
        ax.hist(np.clip(result['normal'], -4, 4), bins=bins, histtype='step', label=name)
    ax.axvspan(-Z90, Z90, color='0.9', zorder=0, label='nominal 90 %')
    ax.set_xlabel('(predicted - true) / std, force along the push')
    ax.set_ylabel('probe steps')
    ax.set_title('Held-out probe trials: wrench intervals against FEM truth')
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Console entry: coverage of the 90 % intervals on every object's probe trials."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='out/coverage', help='output directory')
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--data', default=DATA_DIR, help='folder of the cached fixtures')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--train', type=int, default=PROBE_TRAIN_POKES,
                        help='training pokes of the point model')
    parser.add_argument('--sources', choices=('calibrated', 'fit_only'), default='calibrated',
                        help="uncertainty sources: calibrate_shape's (default) or the joint "
                        "fit's own covariance and residual (before issue 17's second pass)")
    parser.add_argument('--cut', type=float, default=None, metavar='M',
                        help='train on the pokes cut at this depth (m): the trials then press '
                        'past them')
    parser.add_argument('--kappa', type=float, default=EXTRAPOLATION_KAPPA,
                        help='growth of the std past the pokes (0: the model\'s spread alone)')
    args = parser.parse_args(argv)
    results, table = {}, {}
    for name in args.objects:
        surface, curves, _ = load_poke_fixture(name, args.data)
        trials, _, _ = load_probe_fixture(name, args.data)
        print(f'[coverage] {name}: {len(trials)} probe trials, point model on {args.train} '
              f'of {len(curves)} pokes')
        results[name] = probe_coverage(curves, surface, trials, args.train, args.seed,
                                       sources=args.sources, cut=args.cut, kappa=args.kappa)
        table[name] = summary(results[name])
        s = table[name]
        print(f'[coverage] {name}: 90 % intervals cover {s["coverage_normal"]:.0%} of '
              f'{s["steps"]} steps (force along the push; {s["coverage_force"]:.0%} of all '
              f'force and {s["coverage_torque"]:.0%} of all torque components); predicted '
              f'below truth {s["below"]}, above {s["above"]}; median '
              f'width {s["width_over_force"]:.0%} of the force (median relative std '
              f'{s["relative_std"]:.0%})')
    pooled = {key: np.concatenate([np.asarray(r[key]) for r in results.values()])
              if key in ('normal', 'kinds', 'relative_std') else
              np.vstack([np.asarray(r[key]) for r in results.values()])
              for key in ('normal', 'force', 'torque', 'pred', 'std', 'true', 'kinds',
                          'relative_std')}
    table['pooled'] = summary(pooled)
    s = table['pooled']
    print(f'[coverage] pooled: {s["coverage_normal"]:.0%} of {s["steps"]} steps covered (goal '
          f'85-95 %), {s["coverage_force"]:.0%} of all force and {s["coverage_torque"]:.0%} of '
          f'all torque components; median width '
          f'{s["width_over_force"]:.0%} of the force')
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'coverage.json').write_text(json.dumps(table, indent=2))
    _plot(results, out / 'coverage.png')
    print(f'[coverage] wrote {out / "coverage.json"} and {out / "coverage.png"}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
