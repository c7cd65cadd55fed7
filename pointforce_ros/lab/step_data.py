"""Step data from the simulated cell: quasi-static depth steps, a few samples per poke, as CSV.

Another rig often measures a poke as a handful of settled depth steps (5-20 samples) rather
than a 250 Hz stream. :func:`make_step_table` makes such a table from the simulated cell's
object physics (the FEM live contact path of :mod:`pointforce_ros.sim.fem.live`, the same
ground truth the cell streams from), in the documented import format of
:mod:`pointforce_ros.pokes.table`, so the whole product path (CSV import, learner,
``pointforce diagnose``) can be run on it.

Per poke (locations uniform over the object's top, inset by ``margin``):

* the rig's surface point is the true one moved along the normal by a camera bias plus noise
  (``depth_bias``, ``depth_noise``): contact starts at a non-zero nominal depth;
* ``per_poke`` depth steps, evenly from ``start_depth`` before the observed surface down to
  where the true force reaches ``force_limit`` (or ``spec.max_depth``);
* the force is the settled (quasi-static) normal force at the true depth plus white noise of
  ``force_noise`` (a settled step averages many sensor samples, hence a smaller noise than one
  250 Hz sample's).

Same seed, same table. Usage::

    python -m pointforce_ros.lab.step_data --out steps.csv [--object lamb] [--pokes 64]
        [--per-poke 10] [--seed 0] [--score 48]

A bad argument or object, or an ``--out`` that cannot be written, is one error line and exit
status 2.

``--score N`` then learns the first ``N`` pokes through the CSV import and the learner
(:func:`score_step_table`) and prints the held-out error on the others against the noise-free
force.
"""

import argparse
import io
from pathlib import Path
import sys
from typing import Dict

import numpy as np

from pointforce_ros import arguments
from pointforce_ros.errors import InvalidInput, PointforceError
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.pokes.table import load_pokes, surface_from_records, TABLE_COLUMNS
from pointforce_ros.sim.fem.live import LiveContact
from pointforce_ros.sim.objects import load_object

MAX_STEPS = 1000
"""Most depth steps per poke (step data has 5-20; 10^8 asked numpy for 48 GiB)."""


def make_step_table(out, object_name: str = 'lamb', pokes: int = 64, per_poke: int = 10,
                    seed: int = 0, force_noise: float = 0.02, depth_bias: float = 0.001,
                    depth_noise: float = 0.0003, force_limit: float = 6.0,
                    start_depth: float = 0.0015, step_time: float = 1.0,
                    margin: float = 0.25) -> Dict:
    """Write a step-data table (CSV) of ``pokes`` x ``per_poke`` samples; return its truth.

    Args:
        out: CSV path (parent folders are made).
        object_name: simulated object (``config/objects``); its live contact table must be
            built (``data/fem/live_<object>.npz`` or the cache).
        pokes: locations, one poke each (1..:data:`~pointforce_ros.arguments.MAX_POKES`).
        per_poke: depth steps per poke (2..:data:`MAX_STEPS`).
        seed: seed of locations, camera and force noise.
        force_noise: N, standard deviation of each settled force sample.
        depth_bias: m, the rig's surface lies this far outside the true one (along ``n``).
        depth_noise: m, standard deviation of the surface point along ``n`` per poke.
        force_limit: N, the deepest step is where the true force first reaches this.
        start_depth: m, the first step is this far before the observed surface.
        step_time: s between steps (the table's ``t``).
        margin: fraction of the half size the locations keep from the footprint's edge.

    Returns:
        ``{'path': Path, 'ids': [...], 'depth': (P, S), 'force_true': (P, S),
        'force': (P, S), 'offset': (P,)}``: nominal depths (m), noise-free and measured
        normal forces (N) and each poke's surface offset (m, the true surface lies this far
        below the rig's point).

    Raises:
        InvalidInput: a count or noise out of range.

    """
    if not (1 <= pokes <= arguments.MAX_POKES and 2 <= per_poke <= MAX_STEPS):
        raise InvalidInput(f'make_step_table: need pokes in 1..{arguments.MAX_POKES} and '
                           f'per_poke in 2..{MAX_STEPS}, got {pokes} and {per_poke}')
    if force_noise < 0 or depth_noise < 0 or force_limit <= 0:
        raise InvalidInput('make_step_table: noises must be >= 0 and force_limit > 0')
    spec = load_object(object_name)
    live = LiveContact.load(spec.name, build=False)
    rng = np.random.default_rng(seed)
    cx, cy = spec.centre
    hx, hy = spec.size[0] / 2 * (1 - margin), spec.size[1] / 2 * (1 - margin)
    xy = np.column_stack([rng.uniform(cx - hx, cx + hx, pokes),
                          rng.uniform(cy - hy, cy + hy, pokes)])
    offset = depth_bias + depth_noise * rng.standard_normal(pokes)
    fine = np.linspace(0.0, spec.max_depth, 81)
    ids, depth, truth = [], np.zeros((pokes, per_poke)), np.zeros((pokes, per_poke))
    points, normals = np.zeros((pokes, 3)), np.zeros((pokes, 3))
    for k, (x, y) in enumerate(xy):
        n = np.asarray(spec.top_normal(x, y), dtype=float)
        points[k] = np.asarray(spec.top_point(x, y), dtype=float) + offset[k] * n
        normals[k] = n
        curve = np.array([live.normal_force(x, y, d) for d in fine])
        reach = np.flatnonzero(curve >= force_limit)
        deepest = float(fine[reach[0]]) if len(reach) else float(fine[-1])
        nominal = np.linspace(-start_depth, deepest + offset[k], per_poke)
        true_depth = nominal - offset[k]
        truth[k] = [live.normal_force(x, y, d) if d > 0 else 0.0 for d in true_depth]
        depth[k] = nominal
        ids.append(f'step-{k + 1:04d}')
    force = truth + force_noise * rng.standard_normal(truth.shape)
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    buf.write(','.join(TABLE_COLUMNS) + '\n')
    t = step_time * np.arange(per_poke)
    for k, poke_id in enumerate(ids):
        rows = np.column_stack([t + k * step_time * (per_poke + 5),
                                np.tile(points[k], (per_poke, 1)),
                                np.tile(normals[k], (per_poke, 1)), depth[k], force[k]])
        body = io.StringIO()
        np.savetxt(body, rows, fmt='%.17g', delimiter=',')
        buf.write(''.join(f'{poke_id},{line}\n' for line in body.getvalue().splitlines()))
    path.write_text(buf.getvalue())
    return {'path': path, 'ids': ids, 'depth': depth, 'force_true': truth, 'force': force,
            'offset': offset}


def score_step_table(made: Dict, train: int) -> Dict:
    """Learn the first ``train`` pokes of a made table (CSV import, learner); score the rest.

    Returns ``learned``, ``skipped``, ``prequential`` (N), ``heldout_rmse`` (N, against the
    noise-free force at every step of the held-out pokes), ``peak`` (N) and
    ``deepest_bias`` (N, mean error on the held-out pokes' deepest step).

    Raises:
        InvalidInput: ``train`` leaves no poke to train on or none held out.

    """
    records = load_pokes(made['path'])
    if not 0 < train < len(records):
        raise InvalidInput(f'score_step_table: train must be 1..{len(records) - 1}')
    surface = surface_from_records(records)
    learner = OnlineLearner(None, None, surface, shape_constant=0.004)
    status = learner.learn_records(records[:train])
    index = {tuple(p): i for i, p in enumerate(surface.points)}
    truth = made['force_true'][train:]
    pred = np.array([learner.model.predict(
        np.repeat(surface.features[index[tuple(r.point)]][None], len(r), axis=0),
        r.displacement()) for r in records[train:]])
    err = pred - truth
    return {'learned': status.num_pokes, 'skipped': dict(status.skipped),
            'prequential': status.validation_rmse,
            'heldout_rmse': float(np.sqrt(np.mean(err ** 2))), 'peak': float(truth.max()),
            'deepest_bias': float(np.mean(err[:, -1]))}


def main(argv=None) -> int:
    """Command line: write the table and print its size; 2 on a bad argument or file."""
    parser = argparse.ArgumentParser(prog='python -m pointforce_ros.lab.step_data',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--out', required=True, help='CSV path to write')
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--pokes', type=arguments.poke_count, default=64)
    parser.add_argument('--per-poke', type=arguments.positive_int, default=10)
    parser.add_argument('--seed', type=arguments.seed, default=0)
    parser.add_argument('--score', type=arguments.count, default=0,
                        help='learn this many pokes, score the rest (0: do not)')
    args = parser.parse_args(argv)
    if args.score and not args.score < args.pokes:
        parser.error(f'argument --score: {args.score} leaves no held-out poke of --pokes '
                     f'{args.pokes}')
    try:
        made = make_step_table(args.out, args.object, args.pokes, args.per_poke, args.seed)
        print(f'{made["path"]}: {len(made["ids"])} pokes x {made["depth"].shape[1]} steps '
              f'({args.object}, seed {args.seed})')
        if args.score:
            s = score_step_table(made, args.score)
            print(f'learned {s["learned"]}/{args.score} (skipped {len(s["skipped"])}), '
                  f'prequential RMSE {s["prequential"]:.3f} N; held-out '
                  f'{len(made["ids"]) - args.score} pokes: RMSE {s["heldout_rmse"]:.3f} N '
                  f'({100 * s["heldout_rmse"] / s["peak"]:.1f} % of {s["peak"]:.2f} N), '
                  f'deepest-step mean error {s["deepest_bias"]:+.3f} N')
    except PointforceError as exc:
        print(f'{parser.prog}: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:      # --out a folder, or under a file
        print(f'{parser.prog}: error: {type(exc).__name__}: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
