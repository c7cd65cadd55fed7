"""A rigid probe pressed into the calibrated FEM: force and torque of a wide contact.

The semi-empirical simulator answers a contact query from a point model and a shape function;
this answers the same query from the deformation wing's FEM (seed 001's model, calibrated by
:mod:`.identify` or by :func:`calibrate_young`), so a planner has a second answer for wide
contacts (lines, cylinders) where a shape function is least sure.

Contact is unilateral and frictionless and is checked at face points, not only at nodes (a
probe edge narrower than an element would slip between nodes): every surface node and
``samples`` interior points of each surface triangle. For each point ``X_j`` a ray cast along
``-a`` (``a`` the push direction) gives the probe travel ``t_j`` at which the probe's surface
reaches it, and the probe's outward normal ``n_j`` there: the direction of a frictionless
contact force. At travel ``s`` the point must move along ``n_j`` by at least
``(s - t_j) a . n_j``; with contact forces ``p_j >= 0`` along ``n_j`` on the object and the
linear model's condensed compliance ``G`` (``G_jk`` = motion of point ``j`` along ``n_j`` per
unit force along ``n_k`` at ``k``), the contact state is the linear complementarity problem
``w = G p >= gap``, ``p >= 0``, ``p . (w - gap) = 0``, i.e. the convex QP
``min 1/2 p G p - gap . p`` over ``p >= 0``, solved as a non-negative least-squares problem
through the Cholesky factor of ``G``. ``G`` costs three back-substitutions with the stored
factorisation per node under the probe and is reused for every depth of a push. With
``corotational`` the co-rotation term ``K^-1 g(u)`` (:meth:`.fem.CorotationalFem.
nonlinear_force`) shifts the gaps and the QP is iterated.

Units SI (metres, newtons, newton-metres), frame ``base``. Forces and torques are those on the
probe (the F/T sensor's sign), torques about the given centre.
"""

from dataclasses import dataclass
import numpy as np
from scipy.linalg import cho_factor, solve_triangular
from scipy.optimize import nnls

from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, Mesh, Pose

INTERIOR_SAMPLES = np.array([[4.0, 1.0, 1.0], [1.0, 4.0, 1.0], [1.0, 1.0, 4.0]]) / 6.0
"""(3, 3) barycentric weights of the interior contact points of each surface triangle."""


@dataclass(frozen=True)
class PressResult:
    """A rigid probe pressed into the FEM model, depth by depth.

    Attributes:
        depths: (K,) probe travel along the push direction, metres.
        force: (K, 3) force on the probe, newtons, ``base``.
        torque: (K, 3) torque on the probe about the torque centre, N m, ``base``.
        contacts: (K,) face points in contact.
        max_displacement: (K,) largest surface-point motion along the push, metres.

    """

    depths: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    contacts: np.ndarray
    max_displacement: np.ndarray


def _ray_travel(probe: Mesh, pose: Pose, origins: np.ndarray, direction: np.ndarray):
    """Distance along ``-direction`` from each origin to the posed probe, and the probe's normal.

    Returns:
        ``(travel (P,) metres, inf where the ray misses; normal (P, 3) the probe's outward unit
        normal at the hit, zero where it misses)``.

    """
    # Open3D is the project's ray caster (sim.camera, sim.fem.contact); imported here so
    # that the rest of the wing stays numpy/scipy only
    import open3d as o3d

    verts = pose.apply(np.asarray(probe.vertices, dtype=float))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)),
                        o3d.core.Tensor(np.asarray(probe.triangles, dtype=np.uint32)))
    rays = np.hstack([origins, np.repeat(-direction[None], len(origins), axis=0)])
    hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    travel = hit['t_hit'].numpy().astype(float)
    normal = hit['primitive_normals'].numpy().astype(float)
    normal[~np.isfinite(travel)] = 0.0
    return travel, normal


class RigidProbeContact:
    """Presses rigid probe meshes into one factorised FEM model.

    Args:
        fem: the calibrated model (its modulus and Poisson ratio are used as they are).
        samples: interior contact points per surface triangle (0 or 3), besides the nodes.
        regularisation: a contact compliance added to ``G``'s diagonal, relative to its
            largest entry (keeps ``G`` positive definite where face points share nodes; the
            penetration it allows is that fraction of a point's own compliance times its force).
        reach: face points whose probe travel exceeds the deepest depth by more than this are
            left out of the problem, metres (they cannot touch the probe).
        contact_normal: ``'probe'`` (frictionless: each contact force acts along the probe's
            outward normal where the point meets it) or ``'push'`` (every force along the push
            direction, a simpler model that is wrong for tilted probes: on the cell's trials
            tilted up to 15 deg it put the force off the truth's direction by up to 2 x 7.5
            deg).

    Raises:
        InvalidInput: bad sample count or negative settings.

    """

    def __init__(self, fem: CorotationalFem, samples: int = 3, regularisation: float = 1e-6,
                 reach: float = 0.002, contact_normal: str = 'probe'):
        if int(samples) not in (0, 3) or not regularisation >= 0 or not reach >= 0:
            raise InvalidInput(f'RigidProbeContact: samples must be 0 or 3, regularisation and '
                               f'reach >= 0; got {samples}, {regularisation}, {reach}')
        if contact_normal not in ('probe', 'push'):
            raise InvalidInput(f"RigidProbeContact: contact_normal must be 'probe' or 'push', "
                               f'got {contact_normal!r}')
        self.contact_normal = contact_normal
        self.fem = fem
        mesh = fem.mesh
        surf = mesh.surface_nodes
        tri = mesh.surface_triangles
        # face points as barycentric rows over (up to) three nodes
        nodes = [np.column_stack([surf, surf, surf])]
        bary = [np.tile([1.0, 0.0, 0.0], (len(surf), 1))]
        if int(samples):
            nodes.append(np.repeat(tri, 3, axis=0))
            bary.append(np.tile(INTERIOR_SAMPLES, (len(tri), 1)))
        self.point_nodes = np.concatenate(nodes)
        self.point_bary = np.concatenate(bary)
        self.points = np.einsum('pi,pij->pj', self.point_bary, mesh.nodes[self.point_nodes])
        self.regularisation = float(regularisation)
        self.reach = float(reach)

    def first_contact(self, probe: Mesh, start_pose: Pose, direction) -> float:
        """Probe travel along ``direction`` at which it first touches the model, metres.

        Raises:
            InvalidInput: a zero direction, or a probe whose push misses the object.

        """
        a = as_array(direction, 'direction', (3,))
        if not np.linalg.norm(a) > 0:
            raise InvalidInput('first_contact: direction must be non-zero')
        travel, _ = _ray_travel(probe, start_pose, self.points, a / np.linalg.norm(a))
        if not np.isfinite(travel).any():
            raise InvalidInput('first_contact: the probe misses the object')
        return float(travel[np.isfinite(travel)].min())

    def press(self, probe: Mesh, start_pose: Pose, direction, depths, torque_centre=None,
              corotational: bool = False, max_iter: int = 8) -> PressResult:
        """Press ``probe`` from ``start_pose`` along ``direction`` to each of ``depths``.

        Args:
            probe: rigid probe mesh in its own frame (closed), metres.
            start_pose: probe pose at travel 0 (not yet touching), ``base``.
            direction: (3,) push direction (normalised here), ``base``.
            depths: (K,) increasing probe travel, metres.
            torque_centre: (3,) torque reference (default: the start position), metres.
            corotational: iterate the co-rotation term (default: the linear model).
            max_iter: co-rotation iterations per depth.

        Returns:
            :class:`PressResult` (zero force at depths before contact).

        Raises:
            InvalidInput: bad shapes, or a probe that already overlaps the object at travel 0.

        """
        a = as_array(direction, 'direction', (3,))
        if not np.linalg.norm(a) > 0:
            raise InvalidInput('press: direction must be non-zero')
        a = a / np.linalg.norm(a)
        depths = as_array(depths, 'depths', (None,))
        centre = (np.asarray(start_pose.position, dtype=float) if torque_centre is None
                  else as_array(torque_centre, 'torque_centre', (3,)))
        travel, normal = _ray_travel(probe, start_pose, self.points, a)
        if np.any(travel < -1e-9):
            raise InvalidInput('press: the probe overlaps the object at travel 0')
        if self.contact_normal == 'push':
            normal = np.where(np.isfinite(travel)[:, None], a, 0.0)
        # a point the probe reaches from behind its own normal (a back face) cannot be pushed
        ahead = normal @ a
        near = np.flatnonzero((travel <= float(depths.max()) + self.reach) & (ahead > 0.05))
        k = len(depths)
        force = np.zeros((k, 3))
        torque = np.zeros((k, 3))
        contacts = np.zeros(k, dtype=int)
        max_disp = np.zeros(k)
        if len(near) == 0:
            return PressResult(depths, force, torque, contacts, max_disp)
        fem = self.fem
        pn, pb, nu = self.point_nodes[near], self.point_bary[near], normal[near]
        nodes, inv = np.unique(pn, return_inverse=True)
        inv = inv.reshape(pn.shape)
        n_nodes = len(nodes)
        # D (3 n_nodes, m): the nodal load of unit contact forces p_j along nu_j, and its
        # transpose gives each point's motion along its own nu_j
        d = np.zeros((3 * n_nodes, len(near)))
        cols = np.arange(len(near))
        for c in range(3):
            np.add.at(d, (3 * inv + c, np.repeat(cols[:, None], 3, axis=1)),
                      pb * nu[:, c:c + 1])
        load = np.zeros((fem.ndof, 3 * n_nodes))
        dof = (3 * nodes[:, None] + np.arange(3)).ravel()
        load[dof, np.arange(3 * n_nodes)] = 1.0
        comp = fem.solve_linear(load)  # (ndof, 3 n): displacement per unit nodal force
        g = d.T @ comp[dof] @ d
        g = 0.5 * (g + g.T)
        g[np.diag_indices_from(g)] += self.regularisation * float(np.max(np.diag(g)))
        chol, _ = cho_factor(g, lower=True)
        chol = np.tril(chol)
        x0 = self.points[near]
        u_g = np.zeros(len(near))
        for i, s in enumerate(depths):
            gap = (s - travel[near]) * ahead[near]  # penetration along each contact normal
            p = np.zeros(len(near))
            for _ in range(int(max_iter) if corotational else 1):
                rhs = solve_triangular(chol, gap - u_g, lower=True)
                p_new, _ = nnls(chol.T, rhs, maxiter=50 * len(near))
                if corotational:
                    u = comp @ (d @ p_new)
                    corr = fem.solve_linear(fem.nonlinear_force(u))
                    u_g_new = d.T @ corr[dof]
                    done = np.abs(p_new - p).sum() <= 1e-4 * max(p_new.sum(), 1e-12)
                    p, u_g = p_new, u_g_new
                    if done:
                        break
                else:
                    p = p_new
            w = g @ p + u_g
            f_on_probe = -p[:, None] * nu
            pos = x0 + w[:, None] * nu
            force[i] = f_on_probe.sum(axis=0)
            torque[i] = np.cross(pos - centre, f_on_probe).sum(axis=0)
            contacts[i] = int(np.sum(p > 0))
            max_disp[i] = float(np.max(w)) if len(w) else 0.0
        return PressResult(depths, force, torque, contacts, max_disp)
