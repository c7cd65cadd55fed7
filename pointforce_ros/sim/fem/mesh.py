"""Structured trilinear hexahedral meshes of objects resting on the table.

A mesh is a tensor-product grid in reference coordinates ``(s, t, zeta)`` mapped onto the
object's shape: a box (optionally with an undulating top) or a dome over an elliptic footprint.
Node ``(i, j, k)`` has index ``(k * ny1 + j) * nx1 + i``; ``k = 0`` is the bottom (on the
table), ``k = nz`` the top. Elements use the usual 8-node ordering (bottom face counter-clockwise
seen from above, then the top face).

All coordinates are metres in the robot ``base`` frame.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from pointforce_ros.errors import InvalidInput

HEX_CORNERS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                        [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=float)
"""(8, 3) reference coordinates of the hexahedron's nodes."""


@dataclass(frozen=True)
class HexMesh:
    """Structured hexahedral mesh.

    Attributes:
        nodes: (N, 3) reference node positions, metres, ``base``.
        elements: (E, 8) node indices per element.
        shape: ``(nx, ny, nz)`` elements per grid direction.
        boundary_faces: (B, 4) node indices of the faces that may be touched (every boundary
            face except the bottom), ordered counter-clockwise seen from outside.
        bottom_nodes: (Nb,) indices of the nodes on the table (``k = 0``).
        top_nodes: (nx + 1, ny + 1) node indices of the top surface, ``[i, j]``.

    """

    nodes: np.ndarray
    elements: np.ndarray
    shape: tuple
    boundary_faces: np.ndarray
    bottom_nodes: np.ndarray
    top_nodes: np.ndarray

    @property
    def n_nodes(self) -> int:
        """Return the number of nodes."""
        return len(self.nodes)

    def centroids(self) -> np.ndarray:
        """(E, 3) element centroids, metres."""
        return self.nodes[self.elements].mean(axis=1)

    def top_faces(self) -> np.ndarray:
        """(nx ny, 4) node indices of the top faces (the first rows of ``boundary_faces``)."""
        return self.boundary_faces[:self.shape[0] * self.shape[1]]

    def top_triangles(self) -> np.ndarray:
        """(2 nx ny, 3) triangles of the top surface over node indices, outward (up) winding."""
        t = self.top_nodes
        a, b, c, d = t[:-1, :-1], t[1:, :-1], t[1:, 1:], t[:-1, 1:]
        tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                              np.stack([a, c, d], -1).reshape(-1, 3)])
        return tri


def graded_axis(lo: float, hi: float, h: float, centre: Optional[float] = None,
                fine_halfwidth: float = 0.0, growth: float = 1.0,
                h_max: Optional[float] = None) -> np.ndarray:
    """1-D node coordinates from ``lo`` to ``hi``, spacing ``h`` near ``centre``, growing away.

    With ``growth == 1`` (or no ``centre``) the spacing is uniform, close to ``h``. Otherwise
    the spacing is ``h`` within ``fine_halfwidth`` of ``centre`` and grows geometrically by
    ``growth`` per element up to ``h_max`` outside it.

    Returns:
        (n,) strictly increasing coordinates including both ends, metres.

    Raises:
        InvalidInput: non-positive size or spacing, or ``growth < 1``.

    """
    if not hi > lo or not h > 0:
        raise InvalidInput(f'graded_axis: need hi > lo and h > 0, got {lo}, {hi}, {h}')
    if growth < 1.0:
        raise InvalidInput(f'graded_axis: growth must be >= 1, got {growth}')
    if centre is None or growth == 1.0:
        n = max(1, int(round((hi - lo) / h)))
        return np.linspace(lo, hi, n + 1)
    h_max = h_max or 20 * h
    c = float(np.clip(centre, lo, hi))

    def one_side(length):
        pts = [0.0]
        step = h
        while pts[-1] < length - 1e-12:
            if pts[-1] >= fine_halfwidth:
                step = min(step * growth, h_max)
            pts.append(pts[-1] + step)
        pts = np.array(pts)
        if len(pts) > 2 and length - pts[-2] < 0.5 * (pts[-1] - pts[-2]):
            pts = np.delete(pts, -2)
        return pts * (length / pts[-1]) if pts[-1] > 0 else pts

    left = c - one_side(c - lo)[::-1] if c > lo else np.array([lo])
    right = c + one_side(hi - c)[1:] if hi > c else np.array([])
    return np.concatenate([left, right])


def structured_hex(s: np.ndarray, t: np.ndarray, zeta: np.ndarray) -> HexMesh:
    """Build a :class:`HexMesh` on the tensor grid ``s x t x zeta`` (positions not yet mapped).

    Args:
        s, t: (nx + 1,), (ny + 1,) node coordinates along x and y.
        zeta: (nz + 1,) node coordinates along z.

    """
    s, t, zeta = (np.asarray(a, dtype=float) for a in (s, t, zeta))
    nx1, ny1, nz1 = len(s), len(t), len(zeta)
    if min(nx1, ny1, nz1) < 2:
        raise InvalidInput('structured_hex: need at least one element per direction')
    kk, jj, ii = np.meshgrid(np.arange(nz1), np.arange(ny1), np.arange(nx1), indexing='ij')
    nodes = np.stack([s[ii], t[jj], zeta[kk]], -1).reshape(-1, 3)
    idx = np.arange(nx1 * ny1 * nz1).reshape(nz1, ny1, nx1)
    n0 = idx[:-1, :-1, :-1]
    elements = np.stack([n0, idx[:-1, :-1, 1:], idx[:-1, 1:, 1:], idx[:-1, 1:, :-1],
                         idx[1:, :-1, :-1], idx[1:, :-1, 1:], idx[1:, 1:, 1:],
                         idx[1:, 1:, :-1]], -1).reshape(-1, 8)
    faces = []
    top = idx[-1]
    faces.append(np.stack([top[:-1, :-1], top[:-1, 1:], top[1:, 1:], top[1:, :-1]], -1))
    for side, reverse in ((idx[:, :, 0], True), (idx[:, :, -1], False)):  # x = min / max
        quad = np.stack([side[:-1, :-1], side[:-1, 1:], side[1:, 1:], side[1:, :-1]], -1)
        faces.append(quad[..., ::-1] if reverse else quad)  # native normal +x
    for side, reverse in ((idx[:, 0, :], False), (idx[:, -1, :], True)):  # y = min / max
        quad = np.stack([side[:-1, :-1], side[:-1, 1:], side[1:, 1:], side[1:, :-1]], -1)
        faces.append(quad[..., ::-1] if reverse else quad)  # native normal -y
    boundary = np.concatenate([f.reshape(-1, 4) for f in faces])
    return HexMesh(nodes=nodes, elements=elements, shape=(nx1 - 1, ny1 - 1, nz1 - 1),
                   boundary_faces=boundary, bottom_nodes=idx[0].ravel(),
                   top_nodes=idx[-1].T.copy())


def map_box(mesh: HexMesh, height_fn) -> HexMesh:
    """Scale each node column to the local top height ``height_fn(x, y)`` (metres)."""
    nodes = mesh.nodes.copy()
    z_top = mesh.nodes[:, 2].max()
    nodes[:, 2] = nodes[:, 2] / z_top * height_fn(nodes[:, 0], nodes[:, 1])
    return _replace_nodes(mesh, nodes)


def square_to_disk(u: np.ndarray, v: np.ndarray):
    """Map the square ``[-1, 1]^2`` onto the unit disk (elliptical grid mapping)."""
    return u * np.sqrt(1.0 - 0.5 * v * v), v * np.sqrt(1.0 - 0.5 * u * u)


def _replace_nodes(mesh: HexMesh, nodes: np.ndarray) -> HexMesh:
    return HexMesh(nodes=nodes, elements=mesh.elements, shape=mesh.shape,
                   boundary_faces=mesh.boundary_faces, bottom_nodes=mesh.bottom_nodes,
                   top_nodes=mesh.top_nodes)


def replace_nodes(mesh: HexMesh, nodes: np.ndarray) -> HexMesh:
    """Return ``mesh`` with node positions ``nodes`` (N, 3), same topology."""
    nodes = np.asarray(nodes, dtype=float)
    if nodes.shape != mesh.nodes.shape:
        raise InvalidInput(f'replace_nodes: expected {mesh.nodes.shape}, got {nodes.shape}')
    return _replace_nodes(mesh, nodes)
