"""Probe trials on the analytic half-space of ``datasets.py``, with a known spatial coupling.

``pointforce cell generate`` makes probe trials with the FEM (minutes each); the tests need a
tiny set in well under a second. The object is ``datasets.OBJECT`` (``HalfSpaceContact``: a flat
top at ``z0`` whose point law is ``k(x, y) d^1.5``). A point law says nothing about how several
contact points share a load, so the ground truth of a paddle or cylinder pressed into it takes
the seed's semi-empirical contact law (:class:`~pointforce_ros.contact.ContactSimulator`, LCP
with ``g(r) = c / (c + r)``) with the *true* point law on the true top and a chosen true shape
constant ``c_true``: a model that learned the point law from pokes is then exact up to what
it learned, and any ``c`` other than ``c_true`` leaves a probe residual that grows with the
contact patch (the spatial coupling the point pokes cannot see).

Trials follow ``cell.generate.probe_trials``: the probe just touches the top at travel 0 and is
pushed along a direction tilted up to ``max_tilt_deg`` from straight down, with a random roll.

``compliance`` (m/N) makes the trials *measured through the arm*: the arm (or table) gives way
by ``compliance`` times the probe's total push-back force along the push, so the probe sits
short of its commanded travel (solved per step with ``effects.forward.solve_retreat``). The
same compliance acting on point pokes only reparametrises each poke's curve; on a wide probe
the total force of every contact point deflects it, which is what makes it identifiable.
"""

import importlib.util
from pathlib import Path

import numpy as np

from pointforce_ros.sim.fem.probes import cylinder_probe, paddle_probe, pose_for_push
from pointforce_ros.contact import ContactSimulator
from pointforce_ros.effects.forward import solve_retreat
from pointforce_ros.pokes.trials import ProbeTrial
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location('diagnose_datasets_probes', HERE / 'datasets.py')
datasets = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(datasets)

HALF = 0.06
"""Half size of the square top the surface covers, metres (the pokes land within 0.03)."""


def top_surface(spacing: float = 0.002) -> Surface:
    """Return the object's true top as a surface grid (normals +z, no colour)."""
    axis = np.arange(-HALF, HALF + 1e-12, spacing)
    x, y = np.meshgrid(axis, axis, indexing='ij')
    points = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, datasets.OBJECT.z0)])
    return Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))


def true_response(surface: Surface) -> BakedResponse:
    """Return the object's point law ``k(x, y) d^p`` on ``surface`` as a baked table."""
    obj = datasets.OBJECT
    depths = np.linspace(0.0, 0.015, 121)
    w = 2.0 * np.pi / obj.wavelength
    k = obj.k0 * (1.0 + obj.ripple * np.sin(w * surface.points[:, 0])
                  * np.sin(w * surface.points[:, 1]))
    forces = k[:, None] * depths[None, :] ** obj.exponent
    slopes = k * obj.exponent * depths[-1] ** (obj.exponent - 1.0)
    return BakedResponse(depths=depths, forces=forces, slopes=slopes)


def make_trials(c_true: float, count: int = 4, seed: int = 3, steps: int = 5,
                max_depth: float = 0.003, max_tilt_deg: float = 10.0, spacing: float = 0.003,
                compliance: float = 0.0):
    """Return ``count`` paddle and ``count`` cylinder trials with ground truth at ``c_true``.

    ``compliance`` > 0: measured through a compliant arm (module docstring); the trials are
    marked ``compliant``.
    """
    rng = np.random.default_rng([int(seed), 11])
    surface = top_surface()
    truth = ContactSimulator(surface, true_response(surface), c_true, spacing=spacing)
    trials = []
    for kind, maker in (('line', paddle_probe), ('cylinder', cylinder_probe)):
        mesh = maker()
        for _ in range(int(count)):
            tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
            azimuth = rng.uniform(0.0, 2 * np.pi)
            direction = np.array([np.sin(tilt) * np.cos(azimuth),
                                  np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
            roll = rng.uniform(0.0, np.pi)
            top = np.array([rng.uniform(-0.012, 0.012), rng.uniform(-0.012, 0.012),
                            datasets.OBJECT.z0])
            world = pose_for_push(top, direction, roll).apply(mesh.vertices)
            clearance = float(np.max((datasets.OBJECT.z0 - world[:, 2]) / np.cos(tilt)))
            start = pose_for_push(top - direction * clearance, direction, roll)
            depths = np.linspace(0.0, max_depth, steps + 1)[1:]
            poses = [pose_for_push(start.position + d * direction, direction, roll)
                     for d in depths]
            if compliance > 0:
                rows = np.array([np.concatenate([p.position, p.orientation]) for p in poses])

                def push_back(index, shift, rows=rows, mesh=mesh, direction=direction,
                              centre=start.position):
                    moved = rows[index].copy()
                    moved[:, :3] -= shift[:, None] * direction
                    out = truth.query_batch(mesh, moved, direction, centre)
                    return -(out.wrenches[:, :3] @ direction)

                shift, _ = solve_retreat(push_back, float(compliance), len(poses))
                poses = [pose_for_push(p.position - s * direction, direction, roll)
                         for p, s in zip(poses, shift)]
            out = truth.query_batch(mesh, poses, direction, start.position)
            trials.append(ProbeTrial(kind=kind, mesh=mesh, start=start, direction=direction,
                                     torque_centre=start.position.copy(), depths=depths,
                                     force=out.wrenches[:, :3], torque=out.wrenches[:, 3:],
                                     compliant=compliance > 0))
    return trials
