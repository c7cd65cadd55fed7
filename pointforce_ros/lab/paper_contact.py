"""The seed paper's contact algorithm as written (seed 000, IV): the benchmark baseline.

Per query: sample the rigid mesh, project every rigid sample and every surface point onto the
plane normal to the approach direction, find each sample's 3 nearest surface points by brute
force (the full sample-by-surface distance matrix), average positions/features and nominal
displacements (eq. 1), keep ``d > 0``, build the dense ``G`` (eq. 2-3), solve it with the
paper's iterative scheme (:func:`solve_lcp_paper`) and query the regressor ``y`` for
``y(q, d)`` and ``y(q, d - d~)`` (eq. 4).

Deliberately absent (they are what :class:`ContactSimulator` adds): front-most selection, the
facing-surface and over-the-surface tests, de-duplication, any caching between calls.
"""

import time
from typing import Callable

import numpy as np

from pointforce_ros.contact.lcp import shape_matrix, solve_lcp_paper
from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.contact.simulator import _positive, ContactResult, normalise_approach
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, Mesh, Pose, Surface, Wrench


class PaperContactSimulator:
    """Seed 000's contact simulator as written, with a regressor queried on every call.

    Args:
        surface: equilibrium surface (``N`` points, ``base``).
        predict: ``predict(features, d) -> forces``: ``features`` (M, 9) rows ``[p, rgb, n]``
            of the estimated equilibrium points (the 3 neighbours' features averaged),
            ``d`` (M,) metres; returns (M,) newtons (a fitted regressor in the paper).
        c: shape-function constant, metres.
        spacing: rigid-mesh sampling step, metres.

    Attributes:
        last_timing: seconds spent in the last query on ``collision``, ``lcp`` and ``model``.

    """

    def __init__(self, surface: Surface, predict: Callable, c: float, spacing: float = 0.003):
        if not isinstance(surface, Surface):
            raise InvalidInput('PaperContactSimulator: surface must be a types.Surface')
        if not callable(predict):
            raise InvalidInput('PaperContactSimulator: predict must be callable')
        self.surface = surface
        self.predict = predict
        self.c = _positive('c', c)
        self.spacing = _positive('spacing', spacing)
        self.last_timing = {}

    def query(self, mesh: Mesh, pose: Pose, approach, torque_centre) -> ContactResult:
        """Contact wrench of ``mesh`` at ``pose`` moving along ``approach`` (see module doc).

        Raises:
            InvalidInput: non-unit approach or malformed centre.
            NotConverged: ``G`` singular (duplicate contact points), which the paper's scheme
                cannot handle.

        """
        a = normalise_approach(approach)
        centre = as_array(torque_centre, 'torque_centre', (3,))
        t0 = time.perf_counter()
        local, _ = sample_mesh_surface(mesh, self.spacing)
        rigid = pose.apply(local)
        helper = np.eye(3)[int(np.argmin(np.abs(a)))]
        e1 = np.cross(a, helper)
        e1 /= np.linalg.norm(e1)
        basis = np.column_stack([e1, np.cross(a, e1)])
        surf2 = self.surface.points @ basis
        rig2 = rigid @ basis
        dist2 = (np.einsum('ij,ij->i', rig2, rig2)[:, None] - 2.0 * rig2 @ surf2.T
                 + np.einsum('ij,ij->i', surf2, surf2)[None, :])
        nbr = np.argpartition(dist2, 2, axis=1)[:, :3]
        pts, nrm = self.surface.points[nbr], self.surface.normals[nbr]
        d = -np.einsum('kji,kji->k', rigid[:, None, :] - pts, nrm) / 3.0
        keep = d > 0.0
        rigid, nbr, d = rigid[keep], nbr[keep], d[keep]
        feats = self.surface.features[nbr].mean(axis=1)
        q = feats[:, :3]
        nq = feats[:, 6:9] / np.maximum(np.linalg.norm(feats[:, 6:9], axis=1, keepdims=True),
                                        1e-300)
        feats[:, 6:9] = nq
        t1 = time.perf_counter()
        if len(d) == 0:
            self.last_timing = dict(collision=t1 - t0, lcp=0.0, model=0.0)
            zero = Wrench(force=np.zeros(3), torque=np.zeros(3), frame=self.surface.frame,
                          torque_centre=centre)
            return ContactResult(wrench=zero, contact_count=0, max_displacement=0.0,
                                 displaced_indices=np.zeros(0, dtype=np.int64),
                                 displacements=np.zeros(0),
                                 rigid_points_in_contact=np.zeros((0, 3)), lcp_residual=0.0)
        G = shape_matrix(q, self.c)
        sol = solve_lcp_paper(G, d)
        t2 = time.perf_counter()
        act = sol.x > 0.0
        fa = np.asarray(self.predict(feats[act], d[act]), dtype=np.float64)
        fb = np.asarray(self.predict(feats[act], d[act] - sol.x[act]), dtype=np.float64)
        f = fa - fb
        t3 = time.perf_counter()
        force = f[:, None] * nq[act]
        torque = np.cross(rigid[act] - centre, force)
        self.last_timing = dict(collision=t1 - t0, lcp=t2 - t1, model=t3 - t2)
        wrench = Wrench(force=force.sum(axis=0), torque=torque.sum(axis=0),
                        frame=self.surface.frame, torque_centre=centre)
        return ContactResult(
            wrench=wrench, contact_count=int(act.sum()),
            max_displacement=float((G @ sol.x).max()), displaced_indices=nbr[act, 0],
            displacements=d[act], rigid_points_in_contact=rigid[act],
            lcp_residual=sol.residual, contact_points=q[act], contact_normals=nq[act],
            nominal_displacements=d[act], actual_displacements=sol.x[act], contact_forces=f,
            candidate_count=len(d))
