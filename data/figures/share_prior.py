#!/usr/bin/env python3
"""How uncertain is the held-out share of a few calibration pushes? (a study, session 24)

``calibrate_shape`` stores the share of the force ``(c, L)`` misses on a push it has not seen
(``relative_std``): the root mean square of ``n`` leave-one-push-out errors, widened by
Student's t with ``n`` degrees of freedom. With ``n`` = 2-4 that estimate is itself noisy, and
``coverage.py`` shows it: thin_layer's first-but-one line is held out with a share of 16 % from
the other four trials, which predict each other well, and its interval covers 1 of 4 steps;
with that line among the calibrating trials the share is 26-33 %.

This study caches, for every object's probe trials (figure 2's fixtures, point model on 10
random pokes, seed 0, as ``python -m pointforce_ros.lab.coverage``), each trial scored from the
object's other trials: the wrench, its standard deviation WITHOUT the relative share (response,
shape and lateral parts), the truth, the trial's own held-out relative error and the other
trials' leave-one-out errors. From that cache any rule for the share can be scored without a
simulator. ``--analyse`` compares today's rule with a share shrunk towards a population value
(a scaled inverse chi-square prior with ``nu0`` degrees of freedom and scale ``s0``, the
conjugate prior of a normal variance: posterior ``s^2 = (nu0 s0^2 + n s^2) / (nu0 + n)``, a new
push's error Student's t with ``nu0 + n`` degrees of freedom), the prior fitted on the OTHER
objects' trials (leave one object out) by maximising the marginal likelihood of their held-out
errors.

Result (session 24, ``share_prior.log``; the cache ``share_prior_cache.json``, 12 min on two
cores; ``--analyse`` reads it in a second): the cache reproduces the coverage lab exactly (64
of 76 steps, 84.2 %). The objects' held-out errors (plush 38, 18, 7, 16, 7 %; vest 43, 16, 25,
12, 28 %; lamb 31, 9, 11, 14, 9 %; dome 3, 8, 9, 11 %; thin_layer 11, 39, 9, 17, 11 %) give
the prior no room: the marginal likelihood is largest at ``nu0`` -> infinity (one share for
every object, 18-22 % from the other four), which covers the same 64 of 76 steps (plush 87,
vest 77, lamb 100, dome 92, thin_layer 71 %; median width 97 % of the force against 101 %).
The misses are not a noisy share but one trial per object the others cannot anticipate (the
first line of plush, vest and lamb, thin_layer's second: 31-43 % off where the others predict
each other within 3-17 %); a pooled share cannot cover them without widening every interval.
Not in the product.

What does help (``--full-loo``, 12 min on two cores, adds ``inner_full`` to the cache): the
other trials' leave-one-out errors were taken at the joint ``L``, which the trial left out had
helped choose. Refitting ``L`` as well in each inner fit (``(c, L)`` over ``DECAY_GRID`` on
the remaining three trials) raises the errors where ``L`` is not pinned down (with
thin_layer's second line held out, its first line predicted from the last three trials alone
is 35 % off against 15 %, and the second line's share goes from 16 to 26 %), and the
intervals cover 68 of 76 steps (89.5 %; plush 93, vest 92, lamb 93, dome 83, thin_layer
86 %), median width 115 % of the force (was 101 %). Not tuned on these steps: it is the leave-one-out the share
claims to be. ``calibrate_shape`` does this since session 24 (with three or more pushes; two
cannot choose ``L`` from one), so a cache made now holds these errors as ``inner`` as well
(the committed cache was made before, with ``inner`` at the joint ``L``).

Usage: python data/figures/share_prior.py [--objects plush vest] [--cache FILE] [--full-loo]
       python data/figures/share_prior.py --analyse [--cache FILE]
"""

import argparse
import json
from pathlib import Path

import numpy as np

from pointforce_ros.contact.identify import (_relative_error, calibrate_shape, DECAY_GRID,
                                             identify_shape_constant_from_probes)
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.contact.uncertainty import wrench_uncertainty
from pointforce_ros.lab.figures import (bake_depths, DEFAULT_C, load_poke_fixture,
                                        load_probe_fixture, PROBE_TRAIN_POKES, trial_poses)
from pointforce_ros.model.files import ContactModel
from pointforce_ros.response.ours import ContactGpModel

HERE = Path(__file__).resolve().parent
OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
CACHE = HERE / 'share_prior_cache.json'


def push_of(trial) -> tuple:
    """A probe trial as ``calibrate_shape`` takes a push."""
    return trial['mesh'], trial_poses(trial), trial['direction'], trial['force']


def coverage_setup(name: str, data=HERE, seed: int = 0) -> tuple:
    """``(surface, trials, baked, nominal)`` of one object as the coverage lab draws them.

    The point model on ``PROBE_TRAIN_POKES`` random pokes (``default_rng([seed, 17])``, as
    :func:`pointforce_ros.lab.coverage.probe_coverage`), baked on the fixture's surface, and
    the simulator at the figures' default ``c``.
    """
    surface, curves, _ = load_poke_fixture(name, data)
    trials, _, _ = load_probe_fixture(name, data)
    rng = np.random.default_rng([int(seed), 17])
    train = [curves[i] for i in rng.choice(len(curves), size=PROBE_TRAIN_POKES, replace=False)]
    baked = ContactGpModel().fit(train, surface).bake(surface, bake_depths(curves))
    return surface, trials, baked, ContactSimulator(surface, baked, DEFAULT_C)


def object_rows(name: str, data=HERE, seed: int = 0) -> list:
    """Per trial of one object: the cached quantities of the module docstring."""
    surface, trials, baked, nominal = coverage_setup(name, data, seed)
    rows = []
    for j, trial in enumerate(trials):
        others = [push_of(t) for i, t in enumerate(trials) if i != j]
        cal = calibrate_shape(nominal, others, decays=DECAY_GRID)
        meta = dict(cal.sources())
        model = ContactModel(surface=surface, response=baked, shape_constant=cal.fit.c,
                             version=1, shape_decay=cal.fit.decay, meta=meta)
        out = wrench_uncertainty(model, trial['mesh'], trial_poses(trial), trial['direction'],
                                 trial['torque_centre'], relative_std=0.0)
        a = -np.asarray(trial['direction'], dtype=float)
        true = np.asarray(trial['force'], dtype=float)
        along_pred, along_true = out.wrench[:, :3] @ a, true @ a
        error = float(np.sqrt(np.mean((along_pred - along_true) ** 2))
                      / np.sqrt(np.mean(along_true ** 2)))
        rows.append({'trial': j, 'kind': str(trial['kind']), 'c': cal.fit.c,
                     'decay': cal.fit.decay if np.isfinite(cal.fit.decay) else None,
                     'relative_std': cal.relative_std, 'in_sample': cal.in_sample_std,
                     'inner': [e for _, e in cal.held_out if np.isfinite(e)],
                     'error': error, 'approach': a.tolist(),
                     'wrench': out.wrench.tolist(), 'std0': out.std.tolist(),
                     'true_force': true.tolist(),
                     'true_torque': np.asarray(trial['torque'], dtype=float).tolist()})
        print(f'[share] {name} trial {j} ({trial["kind"]}): held-out error {error:.0%}, '
              f'inner {", ".join(f"{e:.0%}" for e in rows[-1]["inner"])}, share '
              f'{cal.relative_std:.0%}', flush=True)
    return rows


def full_loo_errors(name: str, data=HERE, seed: int = 0) -> dict:
    """Per held-out trial ``j``: the others' leave-one-out errors with ``(c, L)`` BOTH refitted.

    ``calibrate_shape`` refits ``c`` on the others at the joint ``L`` (fitted with the trial it
    then predicts); here each inner fit chooses its own ``L`` from :data:`DECAY_GRID` too. The
    fit on trials ``all - {j, k}`` serves both ``(j, k)`` and ``(k, j)``.
    """
    surface, trials, baked, nominal = coverage_setup(name, data, seed)
    pushes = [push_of(t) for t in trials]
    n = len(trials)
    fits = {}
    out = {}
    for j in range(n):
        errors = []
        for k in range(n):
            if k == j:
                continue
            key = frozenset((j, k))
            if key not in fits:
                fit = identify_shape_constant_from_probes(
                    nominal, [p for i, p in enumerate(pushes) if i not in key],
                    decays=DECAY_GRID)
                fits[key] = nominal.with_shape_constant(fit.c, fit.decay)
            errors.append(_relative_error(fits[key], pushes[k]))
        out[j] = errors
        print(f'[share] {name} trial {j}: full leave-one-out errors of the others '
              + ', '.join(f'{e:.0%}' for e in errors), flush=True)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS), choices=OBJECTS)
    parser.add_argument('--cache', default=str(CACHE))
    parser.add_argument('--analyse', action='store_true')
    parser.add_argument('--full-loo', action='store_true', help="add each trial's inner "
                        "errors with (c, L) both refitted to the cache")
    args = parser.parse_args(argv)
    path = Path(args.cache)
    cache = json.loads(path.read_text()) if path.exists() else {}
    if args.analyse:
        from share_prior_analysis import analyse   # this folder
        analyse(cache)
        return 0
    for name in args.objects:
        if args.full_loo:
            errors = full_loo_errors(name)
            for row in cache[name]:
                row['inner_full'] = errors[row['trial']]
        else:
            cache[name] = object_rows(name)
        path.write_text(json.dumps(cache))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
