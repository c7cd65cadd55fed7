"""Trilinear hexahedra: shape functions, neo-Hookean and linear elasticity, vectorised assembly.

Volumetric locking at Poisson ratios up to ~0.49 is avoided by selective-reduced integration:
the isochoric energy is integrated with 2x2x2 Gauss points, the volumetric energy at the element
centre (one point, weight = element volume). In the small-strain limit this is the classic
selective-reduced hexahedron; at finite strain it is variationally consistent, so the tangent is
symmetric.

Strain energy per unit reference volume (compressible neo-Hookean, decoupled form)::

    W(F) = mu / 2 (J^(-2/3) tr(F^T F) - 3) + kappa / 4 (J^2 - 1 - 2 ln J)

with ``mu = E / (2 (1 + nu))`` and ``kappa = E / (3 (1 - 2 nu))``; its linearisation at
``F = I`` is isotropic linear elasticity with the same ``E`` and ``nu``.
Units are SI throughout (Pa, m, N).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from pointforce_ros.sim.fem.mesh import HEX_CORNERS, HexMesh
from pointforce_ros.errors import InvalidInput

GAUSS_2 = HEX_CORNERS / np.sqrt(3.0)
"""(8, 3) 2x2x2 Gauss points in the reference cube (unit weights)."""


def shape_functions(xi: np.ndarray) -> np.ndarray:
    """(Q, 8) trilinear shape functions at reference points ``xi`` (Q, 3)."""
    xi = np.atleast_2d(xi)
    return np.prod(1.0 + xi[:, None, :] * HEX_CORNERS[None], axis=-1) / 8.0


def shape_gradients(xi: np.ndarray) -> np.ndarray:
    """(Q, 8, 3) derivatives of the shape functions with respect to ``xi`` (Q, 3)."""
    xi = np.atleast_2d(xi)
    f = 1.0 + xi[:, None, :] * HEX_CORNERS[None]  # (Q, 8, 3)
    out = np.empty(f.shape)
    for d in range(3):
        others = [o for o in range(3) if o != d]
        out[..., d] = HEX_CORNERS[None, :, d] * f[..., others[0]] * f[..., others[1]] / 8.0
    return out


@dataclass(frozen=True)
class ElementGeometry:
    """Per-element reference geometry of a :class:`HexMesh`.

    Attributes:
        grad: (E, 8, 8, 3) shape-function gradients d N_a / d X at each Gauss point, 1/m.
        wdet: (E, 8) Gauss weight times Jacobian determinant, m^3.
        grad_c: (E, 8, 3) gradients at the element centre, 1/m.
        volume: (E,) element volumes, m^3.

    """

    grad: np.ndarray
    wdet: np.ndarray
    grad_c: np.ndarray
    volume: np.ndarray


def element_geometry(mesh: HexMesh) -> ElementGeometry:
    """Precompute reference gradients and volumes.

    Raises:
        InvalidInput: an element with a non-positive Jacobian (inverted or degenerate).

    """
    xe = mesh.nodes[mesh.elements]  # (E, 8, 3)

    def grads(dn):  # dn (Q, 8, 3)
        jac = np.einsum('eai,qaj->eqij', xe, dn)
        det = np.linalg.det(jac)
        if np.any(det <= 0):
            bad = int(np.argmin(det.min(axis=1)))
            raise InvalidInput(f'element_geometry: element {bad} is inverted or degenerate '
                               f'(min Jacobian {det.min():.3g}); coarsen the mesh or fix the '
                               'geometry mapping')
        inv = np.linalg.inv(jac)
        return np.einsum('qaj,eqjk->eqak', dn, inv), det

    grad, det = grads(shape_gradients(GAUSS_2))
    grad_c, _ = grads(shape_gradients(np.zeros((1, 3))))
    wdet = det
    return ElementGeometry(grad=grad, wdet=wdet, grad_c=grad_c[:, 0], volume=wdet.sum(axis=1))


def lame(young: np.ndarray, poisson: np.ndarray):
    """Shear and bulk moduli ``(mu, kappa)`` in Pa from ``E`` (Pa) and ``nu`` (< 0.5).

    Raises:
        InvalidInput: ``E <= 0`` or ``nu`` outside ``(-1, 0.5)``.

    """
    young = np.asarray(young, dtype=float)
    poisson = np.asarray(poisson, dtype=float)
    if np.any(young <= 0) or np.any(poisson <= -1) or np.any(poisson >= 0.5):
        raise InvalidInput('lame: need E > 0 and -1 < nu < 0.5 (nearly incompressible is '
                           'fine up to ~0.49)')
    return young / (2 * (1 + poisson)), young / (3 * (1 - 2 * poisson))


def _inv_det(f):
    det = np.linalg.det(f)
    return np.linalg.inv(f), det


def isochoric(f: np.ndarray, mu: np.ndarray, tangent: bool = True):
    """Isochoric neo-Hookean energy density, first Piola stress and material tangent.

    Args:
        f: (..., 3, 3) deformation gradients with positive determinant.
        mu: shear modulus broadcastable to ``f.shape[:-2]``, Pa.

    Returns:
        ``(w (...), P (..., 3, 3), A (..., 3, 3, 3, 3) or None)`` with ``A[i,J,k,L] =
        dP[i,J] / dF[k,L]``.

    """
    finv, det = _inv_det(f)
    i1 = np.einsum('...ij,...ij->...', f, f)
    a = det ** (-2.0 / 3.0)
    mu = np.asarray(mu, dtype=float)
    w = 0.5 * mu * (a * i1 - 3.0)
    finv_t = np.swapaxes(finv, -1, -2)
    p = (mu * a)[..., None, None] * (f - (i1 / 3.0)[..., None, None] * finv_t)
    if not tangent:
        return w, p, None
    eye = np.eye(3)
    s = (mu * a)[..., None, None, None, None]
    t1 = np.einsum('ik,JL->iJkL', eye, eye)
    t2 = np.einsum('...Lk,...iJ->...iJkL', finv, f)
    t3 = np.swapaxes(np.swapaxes(t2, -4, -2), -3, -1)  # F_kL Finv_Ji
    t4 = np.einsum('...Lk,...Ji->...iJkL', finv, finv)
    t5 = np.einsum('...Jk,...Li->...iJkL', finv, finv)
    i1b = i1[..., None, None, None, None]
    a_t = s * (t1 - (2.0 / 3.0) * (t2 + t3) + (2.0 / 9.0) * i1b * t4 + (i1b / 3.0) * t5)
    return w, p, a_t


def volumetric(f: np.ndarray, kappa: np.ndarray, tangent: bool = True):
    """Volumetric energy ``kappa/4 (J^2 - 1 - 2 ln J)``, its stress and tangent (see above)."""
    finv, det = _inv_det(f)
    kappa = np.asarray(kappa, dtype=float)
    w = 0.25 * kappa * (det * det - 1.0 - 2.0 * np.log(det))
    finv_t = np.swapaxes(finv, -1, -2)
    c1 = 0.5 * kappa * (det * det - 1.0)  # U'(J) J
    p = c1[..., None, None] * finv_t
    if not tangent:
        return w, p, None
    c2 = (kappa * det * det)[..., None, None, None, None]
    a_t = (c2 * np.einsum('...Lk,...Ji->...iJkL', finv, finv)
           - c1[..., None, None, None, None] * np.einsum('...Jk,...Li->...iJkL', finv, finv))
    return w, p, a_t


class Assembler:
    """Vectorised assembly of internal energy, nodal forces and sparse tangent of a hex mesh.

    Args:
        mesh: the mesh.
        young: (E,) Young's modulus per element or (E, 8) per Gauss point, Pa.
        poisson: (E,) or scalar Poisson ratio.

    The sparsity pattern (CSR over all ``3 N`` dofs, dof = ``3 * node + axis``) is built once;
    each assembly only scatters values into it (``np.bincount``).
    """

    def __init__(self, mesh: HexMesh, young, poisson):
        self.mesh = mesh
        n_el = len(mesh.elements)
        young = np.asarray(young, dtype=float)
        young = young[:, None] if young.ndim == 1 else young
        young = np.broadcast_to(young, (n_el, 8))
        poisson = np.asarray(poisson, dtype=float)
        poisson = np.broadcast_to(poisson[:, None] if poisson.ndim == 1 else poisson,
                                  (n_el, 8))
        self.mu, kappa = lame(young, poisson)  # (E, 8) at the Gauss points
        self.kappa = kappa.mean(axis=1)         # (E,) at the element centre
        self.geo = element_geometry(mesh)
        self.ndof = 3 * mesh.n_nodes
        edof = (3 * mesh.elements[:, :, None] + np.arange(3)).reshape(n_el, 24)
        self.edof = edof
        rows = np.repeat(edof, 24, axis=1).ravel()
        cols = np.tile(edof, (1, 24)).ravel()
        keys = rows.astype(np.int64) * self.ndof + cols
        uniq, self._scatter = np.unique(keys, return_inverse=True)
        self._rows = (uniq // self.ndof).astype(np.int32)
        self._cols = (uniq % self.ndof).astype(np.int32)
        indptr = np.zeros(self.ndof + 1, dtype=np.int64)
        np.add.at(indptr, self._rows + 1, 1)
        self._indptr = np.cumsum(indptr)
        self._linear = None

    def csr(self, data: np.ndarray) -> sp.csr_matrix:
        """Wrap values in the pattern's order as a (3N, 3N) CSR matrix."""
        return sp.csr_matrix((data, self._cols, self._indptr), shape=(self.ndof, self.ndof))

    def deformation_gradients(self, u: np.ndarray):
        """Return ``(F (E, 8, 3, 3), Fc (E, 3, 3))``: Gauss points and centres, ``u`` (N, 3)."""
        ue = u[self.mesh.elements]  # (E, 8, 3)
        eye = np.eye(3)
        f = eye + np.einsum('eai,eqaJ->eqiJ', ue, self.geo.grad)
        fc = eye + np.einsum('eai,eaJ->eiJ', ue, self.geo.grad_c)
        return f, fc

    def min_jacobian(self, u: np.ndarray) -> float:
        """Smallest ``det F`` over Gauss points and centres (<= 0 means an inverted element)."""
        f, fc = self.deformation_gradients(u)
        return float(min(np.linalg.det(f).min(), np.linalg.det(fc).min()))

    def energy(self, u: np.ndarray) -> float:
        """Total strain energy, J, or ``inf`` when an element is inverted."""
        f, fc = self.deformation_gradients(u)
        if np.linalg.det(f).min() <= 0 or np.linalg.det(fc).min() <= 0:
            return np.inf
        w_iso, _, _ = isochoric(f, self.mu, tangent=False)
        w_vol, _, _ = volumetric(fc, self.kappa, tangent=False)
        return float(np.sum(w_iso * self.geo.wdet) + np.sum(w_vol * self.geo.volume))

    def forces_tangent(self, u: np.ndarray, tangent: bool = True):
        """Nodal internal forces (3N,) in N and the tangent (3N, 3N) CSR in N/m (or ``None``).

        Raises:
            InvalidInput: an element is inverted (``det F <= 0``); the caller backs off.

        """
        f, fc = self.deformation_gradients(u)
        if np.linalg.det(f).min() <= 0 or np.linalg.det(fc).min() <= 0:
            raise InvalidInput('inverted element')
        _, p_iso, a_iso = isochoric(f, self.mu, tangent)
        _, p_vol, a_vol = volumetric(fc, self.kappa, tangent)
        g, gc, wd, vol = self.geo.grad, self.geo.grad_c, self.geo.wdet, self.geo.volume
        fe = (np.einsum('eq,eqiJ,eqaJ->eai', wd, p_iso, g, optimize=True)
              + np.einsum('e,eiJ,eaJ->eai', vol, p_vol, gc, optimize=True))
        fint = np.bincount(self.edof.ravel(), fe.reshape(-1), minlength=self.ndof)
        if not tangent:
            return fint, None
        ga = g * wd[:, :, None, None]
        tmp = np.einsum('eqaJ,eqiJkL->eqaikL', ga, a_iso, optimize=True)
        ke = np.einsum('eqaikL,eqbL->eaibk', tmp, g, optimize=True)
        tmp = np.einsum('eaJ,eiJkL->eaikL', gc * vol[:, None, None], a_vol, optimize=True)
        ke += np.einsum('eaikL,ebL->eaibk', tmp, gc, optimize=True)
        data = np.bincount(self._scatter, ke.reshape(-1), minlength=len(self._rows))
        return fint, self.csr(data)

    def linear_stiffness(self) -> sp.csr_matrix:
        """Small-strain stiffness (tangent at ``u = 0``), cached, N/m."""
        if self._linear is None:
            _, self._linear = self.forces_tangent(np.zeros((self.mesh.n_nodes, 3)))
        return self._linear
