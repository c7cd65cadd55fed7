"""The set-up the ``demo_floor*.py`` scripts share: the demo's queries, their truth, its model.

Also the force of one query's LCP solution (:func:`lcp_force_z`), the step after the solve that
``demo_floor_local.py`` and ``demo_floor_law.py`` share.

And the replay of a stored demo's last model with ``(c, L)`` from its two pushes
(:func:`served_last_model`, :func:`pushed_answers`), which ``demo_near_replay.py`` and
``demo_layer_replay.py`` share, the same through the service's answer and spread
(:func:`served_variant`, :func:`replay_variants`, for ``demo_streak_replay.py`` and
``demo_paddle_push.py``), and the queries' score and goals (:func:`query_score`,
:func:`meets_demo_goals`) the replays share.

Not a script: ``demo_floor.py``, ``demo_floor_local.py``, ``demo_floor_law.py``,
``demo_floor_pokes.py`` and the replays import it from this folder (a script's folder is on
``sys.path``).
"""

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from pointforce_ros.bringup.demo import (_calibration_pokes, _ground_truth, demo_query_set,
                                         true_point_response)
from pointforce_ros.contact.identify import calibrate_shape, decay_grid
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.contact.uncertainty import wrench_uncertainty, Z90
from pointforce_ros.model.files import load_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.sim.fem.live import LiveContact
from pointforce_ros.sim.objects import load_object


def lcp_force_z(response, nbr, d, x, nq, approach) -> float:
    """Fz of one query's LCP solution: each active contact's force, summed against the approach.

    ``nbr``: (n, 3) surface point indices of each candidate contact's neighbours; ``d``: (n,)
    nominal displacements in m; ``x``: (n,) the LCP solution (each contact's give, m, zero
    where inactive); ``nq``: (n, 3) contact normals, base frame; ``approach``: (3,) unit
    approach direction, base frame. A contact's force is ``F(d) - F(d - x)`` of ``response``
    averaged over its 3 neighbours; the result is the total force along ``-approach``, in N.
    """
    act = np.flatnonzero(x > 0)
    f = np.zeros(len(d))
    if len(act):
        ia = nbr[act].ravel()
        da = np.repeat(d[act], 3)
        xa = np.repeat(x[act], 3)
        hi = response.force(ia, da)
        lo = response.force(ia, da - xa)
        f[act] = (hi - lo).reshape(-1, 3).mean(axis=1)
    return float((f[:, None] * nq).sum(axis=0) @ -np.asarray(approach))


@dataclass(frozen=True)
class DemoQueries:
    """The demo object, its live FEM table and the 9 planner queries with their FEM truth.

    ``queries``: ``(name, mesh, pose, approach, torque centre)`` tuples
    (:func:`~pointforce_ros.bringup.demo.demo_query_set`); ``gt``: ``force`` and ``torque``
    (9, 3) in N and N m, base frame, and ``names``, from ``demo_queries_<object>.npz``.
    """

    spec: object
    live: LiveContact
    queries: list
    gt: dict


@dataclass(frozen=True)
class DemoFloor(DemoQueries):
    """:class:`DemoQueries` and the demo's last point model, as served.

    ``served``: the simulator of ``model_path`` (the captured surface, the learned response,
    the served ``(c, L)`` and decay law).
    """

    model_path: Path
    served: ContactSimulator

    def true_response(self) -> BakedResponse:
        """The TRUE point response below the captured surface at the learned model's depths.

        The live FEM force with the tip where the learned model puts it
        (:func:`~pointforce_ros.bringup.demo.true_point_response`); the slope past the
        last depth continues the last interval's.
        """
        return true_point_response(self.spec, self.live, self.served.surface.points,
                                   self.served.response.depths)

    def response(self, which: str):
        """``'true'``: :meth:`true_response`; ``'learned'``: the demo's learned response."""
        return self.true_response() if which == 'true' else self.served.response


def load_demo_queries(object_name: str) -> DemoQueries:
    """Load the demo object, its live FEM table, its queries and their FEM truth.

    Raises:
        SystemExit: no ground truth for the queries (``demo_queries_<object>.npz`` missing or
            made for other queries).

    """
    spec = load_object(object_name)
    live = LiveContact.load(spec.name, build=False)
    queries = demo_query_set(spec)
    gt, path = _ground_truth(spec, queries)
    if gt is None:
        raise SystemExit(f'no ground truth for the demo queries of {spec.name} ({path})')
    return DemoQueries(spec, live, queries, gt)


def demo_runs_arguments(description: str):
    """Parse ``DEMO_OUT [DEMO_OUT ...] [--object lamb]``; return ``(args, DemoQueries)``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('demo_out', nargs='+', help="demos' --out folders (their cell/models)")
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    return args, load_demo_queries(args.object)


def load_demo_floor(demo_out, object_name: str) -> DemoFloor:
    """:func:`load_demo_queries` and the last model of the demo run in ``demo_out``.

    ``demo_out``: the demo's ``--out`` folder; its ``cell/models/model-v*.npz`` are read.
    """
    base = load_demo_queries(object_name)
    server = WrenchServer()
    model_path = last_model_path(demo_out)
    server.load(model_path)
    return DemoFloor(base.spec, base.live, base.queries, base.gt, model_path,
                     server.simulator())


def replay_arguments(description: str):
    """:func:`demo_runs_arguments` and what a replay scores against.

    Returns ``(args, demo, pushes, true, largest)``: the demo's two calibration pushes (force
    vectors), the queries' true forces (Q, 3) and the largest true force's norm.
    """
    args, demo = demo_runs_arguments(description)
    vectors = _calibration_pokes(demo.spec, vectors=True)
    true = np.asarray(demo.gt['force'], dtype=float)
    return (args, demo, [vectors['sphere'], vectors['rod']], true,
            float(np.max(np.linalg.norm(true, axis=1))))


def last_model_path(demo_out) -> Path:
    """The last model file a stored demo wrote (``<demo_out>/cell/models/model-v*.npz``)."""
    return sorted((Path(demo_out) / 'cell' / 'models').glob('model-v*.npz'))[-1]


def served_last_model(demo_out) -> ContactSimulator:
    """The simulator the contact service serves the last model of the demo in ``demo_out`` with."""
    server = WrenchServer()
    server.load(last_model_path(demo_out))
    return server.simulator()


def pushed_answers(sim: ContactSimulator, pushes, queries):
    """``(calibration, fitted simulator, (Q, 3) forces)``: ``(c, L)`` from ``pushes`` as the
    demo identifies them (:func:`calibrate_shape`, the capped decay grid), then ``queries``."""
    cal = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface))
    fitted = sim.with_shape_constant(cal.fit.c, cal.fit.decay)
    pred = np.array([fitted.query(m, p, a, ctr).wrench.force for _, m, p, a, ctr in queries])
    return cal, fitted, pred


def served_variant(model, sim, pushes, queries, nears=None):
    """``(calibration, (Q, 3) forces, (Q,) Fz std)`` of a stored demo's model as served.

    ``model``: the model file's contents (:func:`~pointforce_ros.model.files.load_model`),
    ``sim``: its simulator as the service serves it (:func:`served_last_model`). ``(c, L)``
    (and the near field with ``nears``) from ``pushes`` through :func:`calibrate_shape` with
    its uncertainty sources, set on the model as the demo sets them, and each query answered
    through :func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty`: the contact
    service's answer and ``wrench_std``.
    """
    cal = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface), nears=nears)
    served = replace(model, shape_constant=cal.fit.c, shape_decay=cal.fit.decay,
                     shape_near=cal.near, meta={**model.meta, **cal.sources()})
    answers = [wrench_uncertainty(served, mesh, [pose], a, centre)
               for _, mesh, pose, a, centre in queries]
    return (cal, np.array([u.wrench[0, :3] for u in answers]),
            np.array([u.std[0, 2] for u in answers]))


def replay_variants(demo_outs, variants, queries, true, largest: float) -> None:
    """Print each run's answers under each ``(name, pushes, nears)`` variant, then a summary.

    Per run and variant (:func:`served_variant`): the calibration, the queries' force RMSE as
    a share of ``largest``, how many ``Fz`` lie below the truth and inside the nominal 90 %
    intervals, the intervals' mean width and each ``Fz`` over its truth; per variant the
    RMSE range, mean and median, the runs meeting both demo goals and the intervals' hits.
    """
    scores = {name: [] for name, _, _ in variants}
    for out in demo_outs:
        model, sim = load_model(last_model_path(out)), served_last_model(out)
        for name, used, nears in variants:
            cal, pred, std = served_variant(model, sim, used, queries, nears)
            pct, below = query_score(pred, true, largest)
            inside = int(np.sum(np.abs(pred[:, 2] - true[:, 2]) <= Z90 * std))
            width = float(np.mean(2 * Z90 * std))
            scores[name].append((pct, below, inside, width))
            print(f'{out} {name:6s}: {cal.near} near field, c {1e3 * cal.fit.c:.2f} mm, L '
                  f'{1e3 * cal.fit.decay:.0f} mm, pushes predicted from the others '
                  f'{100 * cal.relative_std:.0f} %; queries {pct:.1f} %, {below} of 9 below, '
                  f'{inside} of 9 inside (width {width:.2f} N); Fz pred / true '
                  + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for name, rows in scores.items():
        pct = np.array([r[0] for r in rows])
        meet = sum(1 for p, b, _, _ in rows if meets_demo_goals(p, b))
        print(f'{name:6s}: {len(rows)} runs, RMSE {pct.min():.1f}-{pct.max():.1f} % (mean '
              f'{pct.mean():.2f} %, median {np.median(pct):.2f} %), both goals {meet} of '
              f'{len(rows)}; true Fz inside {sum(r[2] for r in rows)} of {9 * len(rows)}, mean '
              f'width {np.mean([r[3] for r in rows]):.2f} N')


def query_score(pred, true, largest: float):
    """``(RMSE of the force vectors as a % of ``largest``, how many Fz lie below the truth)``."""
    pred, true = np.asarray(pred, dtype=float), np.asarray(true, dtype=float)
    pct = 100 * float(np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1)))) / largest
    return pct, int(np.sum(pred[:, 2] < true[:, 2]))


def meets_demo_goals(pct: float, below: int, queries: int = 9) -> bool:
    """Issue 17's demo goals: under 8 % and at most 6 of the 9 queries on one side."""
    return pct < 8.0 and queries - 6 <= below <= 6
