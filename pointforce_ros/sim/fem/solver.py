"""Quasi-static indentation of a hexahedral FE object by a rigid probe: Newton with line search.

The probe is displacement-controlled: at step ``k`` its pose is ``start_pose`` translated by
``depths[k] * direction``. Each step is solved by Newton's method on the total potential
(strain energy + augmented-Lagrangian contact energy) with an Armijo backtracking line search
and a direct sparse solve (SuperLU with a symmetric minimum-degree ordering); a step that fails
is bisected, and :class:`NotConverged` is raised with the step and residual when bisection runs
out. Outputs are in SI units in the ``base`` frame.
"""

from dataclasses import dataclass
import os
import time
from typing import Optional

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from pointforce_ros.sim.fem.contact import (ContactState, RigidProbe, evaluate_contact,
                                            face_points)
from pointforce_ros.sim.fem.hyperelastic import Assembler
from pointforce_ros.sim.fem.mesh import HexMesh
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.types import Mesh, Pose, as_array


_DEBUG = bool(os.environ.get('POINTFORCE_FEM_DEBUG'))


@dataclass(frozen=True)
class IndentationResult:
    """Outputs of a quasi-static indentation, one row per depth step.

    Attributes:
        depths: (K,) probe travel along ``direction`` from the start pose, metres.
        probe_position: (K, 3) probe frame origin, metres, ``base``.
        force: (K, 3) force the object exerts on the probe, newtons, ``base``.
        torque: (K, 3) torque of that force about ``torque_centre``, N m, ``base``.
        table_force: (K, 3) force the table exerts on the object, newtons (equals ``force``
            at equilibrium).
        surface: (K, P, 3) displaced top-surface node positions, metres, ``base``.
        surface_index: (P,) node indices of those surface nodes in the FE mesh.
        max_penetration: (K,) largest probe penetration at convergence, metres.
        contact_points: (K,) number of active contact sample points.
        iterations: (K,) Newton iterations spent on each step (all substeps).
        torque_centre: (3,) metres, ``base``.

    """

    depths: np.ndarray
    probe_position: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    table_force: np.ndarray
    surface: np.ndarray
    surface_index: np.ndarray
    max_penetration: np.ndarray
    contact_points: np.ndarray
    iterations: np.ndarray
    torque_centre: np.ndarray


class FemModel:
    """Hexahedral FE model of an object on a rigid table.

    Args:
        mesh: the mesh (metres, ``base``; bottom nodes on the table).
        young: (E,) or (E, 8) Young's modulus per element (or per Gauss point), Pa.
        poisson: scalar or (E,) Poisson ratio (< 0.5; selective-reduced integration keeps
            0.49 lock-free).
        support: ``'fixed'`` (bottom nodes clamped) or ``'sliding'`` (frictionless table:
            bottom nodes fixed in z only, one node pinned in x and y and a second in y).
        fixed: optional (N, 3) boolean mask of extra fixed dofs (symmetry planes).
        nonlinear: neo-Hookean large deformation (True) or small-strain linear (False).
        penalty_factor: contact penalty per face point ``eps = penalty_factor * E / h``
            (Pa/m) with ``E`` the largest modulus at the face's nodes and ``h`` the face's
            shortest edge, so a soft skin over a hard core is not over-penalised.
        penetration_tol: augmented-Lagrangian stop: largest penetration, metres ...
        penetration_rel: ... or this fraction of the probe travel, whichever is larger.
        contact_faces: (F, 4) faces checked for contact (default: every boundary face but
            the bottom).
        contact_order: Gauss points per face direction for the contact check (3 -> 3x3).

    Raises:
        InvalidInput: bad material values, unknown support, inverted elements.

    """

    def __init__(self, mesh: HexMesh, young, poisson, support: str = 'fixed',
                 fixed: Optional[np.ndarray] = None, nonlinear: bool = True,
                 penalty_factor: float = 200.0, penetration_tol: float = 5e-6,
                 penetration_rel: float = 2e-3,
                 contact_faces: Optional[np.ndarray] = None, contact_order: int = 3):
        self.mesh = mesh
        self.asm = Assembler(mesh, young, poisson)
        self.nonlinear = bool(nonlinear)
        mask = np.zeros((mesh.n_nodes, 3), dtype=bool)
        if support == 'fixed':
            mask[mesh.bottom_nodes] = True
        elif support == 'sliding':
            mask[mesh.bottom_nodes, 2] = True
            bottom = mesh.nodes[mesh.bottom_nodes]
            centre = bottom.mean(axis=0)
            first = mesh.bottom_nodes[np.argmin(np.linalg.norm(bottom - centre, axis=1))]
            far = mesh.bottom_nodes[np.argmax(np.abs(bottom[:, 0] - centre[0]))]
            mask[first, :2] = True
            mask[far, 1] = True
        else:
            raise InvalidInput(f"FemModel: support must be 'fixed' or 'sliding', got {support!r}")
        if fixed is not None:
            mask |= np.asarray(fixed, dtype=bool)
        self.fixed = mask.ravel()
        self.free = np.flatnonzero(~self.fixed)
        faces = mesh.boundary_faces if contact_faces is None else np.asarray(contact_faces)
        self.fp = face_points(mesh, faces, contact_order)
        edges = np.linalg.norm(mesh.nodes[faces] - mesh.nodes[np.roll(faces, 1, 1)], axis=-1)
        self.h_min = float(edges.min())
        e_el = np.asarray(young, dtype=float)
        e_el = e_el.mean(axis=1) if e_el.ndim == 2 else np.broadcast_to(
            e_el, (len(mesh.elements),))
        e_node = np.zeros(mesh.n_nodes)
        np.maximum.at(e_node, mesh.elements.ravel(), np.repeat(e_el, 8))
        e_face = e_node[faces].max(axis=1)
        eps_face = penalty_factor * e_face / edges.min(axis=1)
        self.eps = np.repeat(eps_face, len(self.fp.area) // len(faces))
        self.penetration_tol = float(penetration_tol)
        self.penetration_rel = float(penetration_rel)
        self.newton_tol = 1e-6
        self.stall_tol = 1e-4
        self.max_iter = 30
        self.reuse_iter = 20
        self.linear_rtol = 1e-7
        self.first_step = 0.25e-3
        self._lu = None
        self._lu_shape = None
        self._t_factor = 0.0
        self._t_solve = 0.0
        self.stats = dict(factorisations=0, pcg_iterations=0)

    # -- energy, residual, tangent -------------------------------------------------------
    def _internal(self, u, tangent=True):
        if self.nonlinear:
            return self.asm.forces_tangent(u, tangent)
        k0 = self.asm.linear_stiffness()
        return k0 @ u.ravel(), (k0 if tangent else None)

    def _strain_energy(self, u):
        if self.nonlinear:
            return self.asm.energy(u)
        uf = u.ravel()
        return 0.5 * float(uf @ (self.asm.linear_stiffness() @ uf))

    def _contact(self, u, probe, pose, lam):
        return evaluate_contact(self.fp, self.mesh.nodes + u, probe, pose, self.eps, lam,
                                margin=2 * self.h_min)

    def _contact_vectors(self, cs: ContactState, tangent=True):
        ndof = self.asm.ndof
        nodes = self.fp.nodes[cs.index]  # (A, 4)
        w = self.fp.weights[cs.index]    # (A, 4)
        fnode = w[:, :, None] * cs.force[:, None, :]  # (A, 4, 3)
        dofs = 3 * nodes[:, :, None] + np.arange(3)
        fc = np.bincount(dofs.ravel(), fnode.ravel(), minlength=ndof)
        if not tangent:
            return fc, None
        # Gauss-Newton tangent eps * area * N_a N_b n n^T (active points only).
        active = cs.pressure > 0
        coef = (self.eps[cs.index] * self.fp.area[cs.index])[active]
        nn = np.einsum('pi,pk->pik', cs.normal[active], cs.normal[active])
        ww = np.einsum('pa,pb->pab', w[active], w[active])
        blocks = coef[:, None, None, None, None] * ww[:, :, None, :, None] * nn[:, None, :, None]
        d = dofs[active].reshape(-1, 12)
        rows = np.repeat(d, 12, axis=1).ravel()
        cols = np.tile(d, (1, 12)).ravel()
        kc = sp.csr_matrix((blocks.reshape(-1), (rows, cols)), shape=(ndof, ndof))
        return fc, kc

    def _linear_solve(self, k, r):
        """Solve ``k x = r``: PCG preconditioned by the last factorisation, else refactorise.

        A factorisation (SuperLU, symmetric minimum-degree ordering) is reused across Newton
        iterations and load steps while preconditioned CG converges within an iteration budget:
        at least ``reuse_iter``, and up to half of what one factorisation costs in
        preconditioner solves (measured), since a change of the contact set perturbs the
        tangent by a low-rank term that PCG resolves in about as many iterations as its rank.
        Otherwise the current tangent is factorised.
        """
        if self._lu is not None and self._lu_shape == k.shape:
            op = spla.LinearOperator(k.shape, matvec=self._lu.solve, dtype=float)
            count = [0]

            def cb(_):
                count[0] += 1
            budget = self.reuse_iter
            if self._t_solve > 0:
                budget = int(np.clip(0.5 * self._t_factor / self._t_solve, self.reuse_iter,
                                     10 * self.reuse_iter))
            t0 = time.perf_counter()
            x, info = spla.cg(k, r, rtol=self.linear_rtol, atol=0.0, maxiter=budget,
                              M=op, callback=cb)
            if count[0]:
                self._t_solve = (time.perf_counter() - t0) / count[0]
            self.stats['pcg_iterations'] += count[0]
            if info == 0 and np.all(np.isfinite(x)):
                return x
        kc = k.tocsc()
        self.stats['factorisations'] += 1
        t0 = time.perf_counter()
        try:
            self._lu = spla.splu(kc, permc_spec='MMD_AT_PLUS_A',
                                 options=dict(SymmetricMode=True))
        except RuntimeError:  # exactly singular: least squares step
            self._lu = None
            return spla.lsqr(kc, r, atol=1e-12, btol=1e-12)[0]
        self._t_factor = time.perf_counter() - t0
        self._lu_shape = k.shape
        return self._lu.solve(r)

    def _potential(self, u, probe, pose, lam):
        w = self._strain_energy(u)
        if not np.isfinite(w):
            return np.inf, None
        cs = self._contact(u, probe, pose, lam)
        return w + cs.energy, cs

    # -- Newton ---------------------------------------------------------------------------
    def _newton(self, u, probe, pose, lam):
        """Solve equilibrium for one probe pose from guess ``u``; return (u, cs, iters)."""
        free = self.free
        energy, cs = self._potential(u, probe, pose, lam)
        if not np.isfinite(energy):
            raise NotConverged('initial guess inverts an element')
        res_norm = np.inf
        energy_prev = energy
        for it in range(1, self.max_iter + 1):
            fint, kint = self._internal(u)
            fc, kc = self._contact_vectors(cs)
            r = (fint - fc)[free]
            scale = max(np.abs(fc).sum(), 1e-3)
            res_norm = float(np.linalg.norm(r))
            if res_norm <= self.newton_tol * scale + 1e-9 * np.sqrt(len(r)):
                return u, cs, it - 1, res_norm
            if (it > 1 and res_norm <= self.stall_tol * scale
                    and abs(energy_prev - energy) <= 1e-8 * abs(energy)):
                # energy stationary to round-off, residual small: contact points flickering
                # at the edge of the contact zone would only make the line search crawl
                return u, cs, it - 1, res_norm
            energy_prev = energy
            k = (kint + kc)[free][:, free]
            du_f = -self._linear_solve(k, r)
            du = np.zeros(self.asm.ndof)
            du[free] = du_f
            du = du.reshape(-1, 3)
            slope = float(r @ du_f)
            if slope >= 0:  # not a descent direction (indefinite tangent): gradient step
                du = np.zeros(self.asm.ndof)
                du[free] = -r / max(k.diagonal().max(), 1.0)
                du = du.reshape(-1, 3)
                slope = float(-(r @ r) / max(k.diagonal().max(), 1.0))
            alpha = 1.0
            for _ in range(12):
                trial = u + alpha * du
                e_new, cs_new = self._potential(trial, probe, pose, lam)
                if np.isfinite(e_new) and (e_new <= energy + 1e-4 * alpha * slope
                                           or abs(e_new - energy) <= 1e-11 * abs(energy)):
                    break  # Armijo, or the energy change is below round-off
                alpha *= 0.5
            else:
                if not np.isfinite(e_new) or e_new > energy + 1e-12 * abs(energy):
                    raise NotConverged(f'line search failed (residual {res_norm:.3g} N)')
            if _DEBUG:
                print(f'    it {it} res {res_norm:.3e} scale {scale:.3e} alpha {alpha:.3g} '
                      f'active {len(cs_new.index)} e {e_new:.6e}')
            u, energy, cs = trial, e_new, cs_new
            if alpha * np.abs(du).max() < 1e-13:
                fint, _ = self._internal(u, tangent=False)
                fc, _ = self._contact_vectors(cs, tangent=False)
                res_norm = float(np.linalg.norm((fint - fc)[free]))
                if res_norm <= 1e-3 * max(np.abs(fc).sum(), 1e-3):
                    return u, cs, it, res_norm
        raise NotConverged(f'Newton did not converge in {self.max_iter} iterations '
                           f'(residual {res_norm:.3g} N)')

    def _solve_pose(self, u, probe, pose, lam, travel):
        """Newton + Uzawa updates until the penetration tolerance holds."""
        total = 0
        tol = max(self.penetration_tol, self.penetration_rel * travel)
        pen_last = np.inf
        for _ in range(8):
            u, cs, its, res = self._newton(u, probe, pose, lam)
            total += its
            pen = float(cs.penetration.max()) if len(cs.index) else 0.0
            if _DEBUG:
                print(f'  newton done: {its} its, residual {res:.3g}, penetration {pen:.3g}')
            if pen <= tol or (pen <= 5 * tol and pen > 0.8 * pen_last):
                break  # within tolerance, or the Uzawa updates stagnate close to it
            pen_last = pen
            lam = lam.copy()
            lam[:] = 0.0
            lam[cs.index] = cs.pressure
        return u, cs, total, lam

    def indent(self, probe_mesh: Mesh, start_pose: Pose, direction, depths,
               torque_centre=None, max_bisections: int = 5,
               stop_force: Optional[float] = None,
               keep_solved: bool = False) -> IndentationResult:
        """Push ``probe_mesh`` from ``start_pose`` along ``direction`` through ``depths``.

        Args:
            probe_mesh: rigid probe (``types.Mesh``) in its own frame, metres.
            start_pose: probe pose at depth 0, ``base``.
            direction: (3,) push direction (normalised here), ``base``.
            depths: (K,) increasing probe travel, metres (>= 0).
            torque_centre: (3,) point the torque is taken about, metres (default: the start
                position).
            max_bisections: how often a failing step may be halved.
            stop_force: stop after the first depth whose force along ``-direction`` exceeds
                this (N); the result then holds the depths solved so far (None: all).
            keep_solved: when a step fails after the first one, return the depths solved so
                far instead of raising.

        Raises:
            InvalidInput: bad shapes, non-increasing depths, zero direction.
            NotConverged: a step failed after ``max_bisections`` halvings (message names the
                step, the depth and the residual).

        """
        depths = as_array(depths, 'depths', (None,))
        if len(depths) == 0 or np.any(np.diff(depths) <= 0) or depths[0] < 0:
            raise InvalidInput('depths: need a non-empty, strictly increasing, >= 0 sequence')
        direction = as_array(direction, 'direction', (3,))
        norm = np.linalg.norm(direction)
        if not norm > 0:
            raise InvalidInput('direction: must be non-zero')
        direction = direction / norm
        centre = (start_pose.position if torque_centre is None
                  else as_array(torque_centre, 'torque_centre', (3,)))
        probe = probe_mesh if isinstance(probe_mesh, RigidProbe) else RigidProbe(probe_mesh)
        n = self.mesh.n_nodes
        u = np.zeros((n, 3))
        u_prev, d_prev, d_prev2 = None, 0.0, 0.0
        lam = np.zeros(len(self.fp.area))
        top = self.mesh.top_nodes.ravel()
        rows = []
        d_done = 0.0
        failed = False
        for k, d_target in enumerate(depths):
            iters = 0
            d_from = d_done
            step = d_target - d_from
            if u_prev is None:
                step = min(step, self.first_step)
            bis = 0
            while d_done < d_target - 1e-15:
                d_try = min(d_done + step, d_target)
                pose = Pose(start_pose.position + d_try * direction, start_pose.orientation)
                guess = u
                if u_prev is not None and d_prev > d_prev2:
                    pred = u + (u - u_prev) * (d_try - d_prev) / (d_prev - d_prev2)
                    if self.asm.min_jacobian(pred) > 0.05:
                        guess = pred
                try:
                    u_new, cs, its, lam_new = self._solve_pose(guess, probe, pose, lam, d_try)
                except NotConverged as exc:
                    bis += 1
                    if bis > max_bisections:
                        if keep_solved and rows:
                            failed = True
                            break
                        raise NotConverged(f'step {k} (depth {d_try * 1e3:.3f} mm) failed '
                                           f'after {max_bisections} bisections: {exc}')
                    step *= 0.5
                    continue
                iters += its
                step *= 2.0
                u_prev, d_prev2, d_prev = u, d_prev, d_try
                u, lam, d_done = u_new, lam_new, d_try
            if failed:
                break
            pose = Pose(start_pose.position + d_target * direction, start_pose.orientation)
            cs = self._contact(u, probe, pose, lam)
            fint, _ = self._internal(u, tangent=False)
            fc, _ = self._contact_vectors(cs, tangent=False)
            reaction = (fint - fc).reshape(-1, 3)[self.fixed.reshape(-1, 3).any(axis=1)]
            force = -cs.force.sum(axis=0)
            torque = np.cross(cs.point - centre, -cs.force).sum(axis=0)
            rows.append(dict(
                pos=pose.position, force=force, torque=torque,
                table=(fint - fc).reshape(-1, 3)[self.mesh.bottom_nodes].sum(axis=0)
                if reaction.size else np.zeros(3),
                surface=(self.mesh.nodes + u)[top],
                pen=float(cs.penetration.max()) if len(cs.index) else 0.0,
                count=len(cs.index), iters=iters))
            if stop_force is not None and -(force @ direction) > stop_force:
                break
        return IndentationResult(
            depths=depths[:len(rows)], probe_position=np.array([r['pos'] for r in rows]),
            force=np.array([r['force'] for r in rows]),
            torque=np.array([r['torque'] for r in rows]),
            table_force=np.array([r['table'] for r in rows]),
            surface=np.array([r['surface'] for r in rows]), surface_index=top,
            max_penetration=np.array([r['pen'] for r in rows]),
            contact_points=np.array([r['count'] for r in rows]),
            iterations=np.array([r['iters'] for r in rows]),
            torque_centre=np.asarray(centre, dtype=float))
