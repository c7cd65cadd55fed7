"""Tetrahedral volume meshes for the PyBullet replica, and the legacy VTK file PyBullet loads.

A replica body is built from what the cell knows of the object: its equilibrium surface (the
camera's scan of the top) over a footprint on the table. :func:`heightfield_tet_mesh` fills the
volume between the table (``z = 0``) and the scanned top with a structured grid of columns,
each hexahedron split into six tetrahedra (Kuhn split, consistent across faces), so the mesh is
conforming. :func:`ball_tet_mesh` makes the seed paper's ball. :func:`write_vtk` writes the
legacy ASCII ``UNSTRUCTURED_GRID`` (cell type 10) that ``pybullet.loadSoftBody`` reads.

All lengths are metres, frame ``base`` (``z = 0`` is the table top).
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.errors import DataError, InvalidInput, reading, TEXT_ENCODING
from pointforce_ros.types import as_array

# Kuhn split of the unit cube: corner index = i + 2 j + 4 k; one tet per axis permutation.
_CUBE = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)])
_KUHN = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7],
                  [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])


@dataclass(frozen=True)
class TetMesh:
    """A conforming linear tetrahedral mesh.

    Attributes:
        nodes: (N, 3) node positions, metres, ``base``.
        tets: (M, 4) int64 node indices, each with positive signed volume.
        resolution: nominal element edge length, metres (what a replica records).

    Raises:
        InvalidInput: no tetrahedra, indices out of range, or a tetrahedron of non-positive
            volume.

    """

    nodes: np.ndarray
    tets: np.ndarray
    resolution: float

    def __post_init__(self):
        nodes = as_array(self.nodes, 'TetMesh.nodes', (None, 3))
        tets = as_array(self.tets, 'TetMesh.tets', (None, 4), dtype=np.int64)
        if len(tets) == 0:
            raise InvalidInput('TetMesh: no tetrahedra')
        if tets.min() < 0 or tets.max() >= len(nodes):
            raise InvalidInput(f'TetMesh.tets: node index out of range 0..{len(nodes) - 1}')
        vol = tet_volumes(nodes, tets)
        if np.any(vol <= 0):
            raise InvalidInput(f'TetMesh: {int(np.sum(vol <= 0))} tetrahedra of non-positive '
                               'volume (inverted or degenerate)')
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise InvalidInput(f'TetMesh.resolution: must be > 0, got {self.resolution}')
        object.__setattr__(self, 'nodes', nodes)
        object.__setattr__(self, 'tets', tets)
        object.__setattr__(self, 'resolution', float(self.resolution))

    @property
    def volume(self) -> float:
        """Total volume, cubic metres."""
        return float(tet_volumes(self.nodes, self.tets).sum())

    def bottom_nodes(self, tol: float = 1e-6) -> np.ndarray:
        """Return the indices (K,) of the nodes on the table (``z <= min z + tol``)."""
        z = self.nodes[:, 2]
        return np.flatnonzero(z <= z.min() + tol)


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (M,) of tetrahedra ``tets`` (M, 4) over ``nodes`` (N, 3), cubic metres."""
    a, b, c, d = (nodes[tets[:, i]] for i in range(4))
    return np.einsum('ij,ij->i', np.cross(b - a, c - a), d - a) / 6.0


def _grid_tets(shape: Tuple[int, int, int], keep: np.ndarray) -> np.ndarray:
    """Kuhn tets (6 per kept cell) of a structured node grid of ``shape`` (nx, ny, nz) nodes.

    ``keep`` is a boolean (nx-1, ny-1, nz-1) cell mask. Node (i, j, k) has flat index
    ``(i * ny + j) * nz + k``.
    """
    nx, ny, nz = shape
    ci, cj, ck = np.nonzero(keep)
    corner = ((ci[:, None] + _CUBE[None, :, 0]) * ny
              + (cj[:, None] + _CUBE[None, :, 1])) * nz + (ck[:, None] + _CUBE[None, :, 2])
    return corner[:, _KUHN].reshape(-1, 4)


def _orient(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Swap two indices of every negatively oriented tetrahedron."""
    tets = tets.copy()
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return tets


def _compact(nodes: np.ndarray, tets: np.ndarray):
    used, inverse = np.unique(tets, return_inverse=True)
    return nodes[used], inverse.reshape(tets.shape)


def heightfield_tet_mesh(surface_points, h: float, *, layers: Optional[int] = None,
                         footprint_tol: Optional[float] = None,
                         min_top_fraction: float = 0.25, surface_normals=None) -> TetMesh:
    """Tet mesh of the body between the table (``z = 0``) and a scanned top surface.

    The footprint is the set of grid columns whose centre lies within ``footprint_tol`` of a
    surface point (seen from above); the top height at each node is interpolated linearly from
    the surface points (Gaussian-weighted within one element). Each column is cut into
    ``layers`` equal layers from the table up to its top, so the top is followed exactly.

    Args:
        surface_points: (P, 3) points of the top surface, metres, ``base`` (an equilibrium
            surface; its sides, if present, are ignored through the height interpolation).
        h: element edge length in x and y, metres.
        layers: element layers through the height (default: height / h rounded, at least 2).
        footprint_tol: largest distance (x-y) from a column centre to the nearest surface
            point, metres (default ``0.75 h``).
        min_top_fraction: lowest column top as a fraction of the body's height.
        surface_normals: (P, 3) unit normals of the points; when given, only upward-facing
            points (n_z > 0.5) set the top height (the scan's side points would pull the
            outer columns down).

    Returns:
        The mesh, oriented, with ``resolution = h``.

    Raises:
        InvalidInput: fewer than 10 points, non-positive ``h``, a top below 2 mm, or a
            footprint with fewer than 2 x 2 columns.

    """
    pts = as_array(surface_points, 'surface_points', (None, 3))
    if len(pts) < 10:
        raise InvalidInput(f'heightfield_tet_mesh: need at least 10 surface points, got '
                           f'{len(pts)}')
    if not (np.isfinite(h) and h > 0):
        raise InvalidInput(f'heightfield_tet_mesh: h must be > 0, got {h}')
    if pts[:, 2].max() < 0.002:
        raise InvalidInput('heightfield_tet_mesh: the surface lies on the table (top below '
                           '2 mm): nothing to mesh')
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    heights = pts
    if surface_normals is not None:
        normals = as_array(surface_normals, 'surface_normals', (len(pts), 3))
        if np.count_nonzero(normals[:, 2] > 0.5) >= 10:
            heights = pts[normals[:, 2] > 0.5]
    n_xy = np.maximum(np.round((hi - lo) / h).astype(int), 1) + 1
    xs = np.linspace(lo[0], hi[0], n_xy[0])
    ys = np.linspace(lo[1], hi[1], n_xy[1])
    top_height = float(np.percentile(pts[:, 2], 95))
    nz = layers or max(2, int(round(top_height / h)))
    nz_nodes = nz + 1
    tree = cKDTree(pts[:, :2])
    tol = 0.75 * h if footprint_tol is None else float(footprint_tol)
    cx, cy = np.meshgrid(0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1]), indexing='ij')
    dist, _ = tree.query(np.stack([cx.ravel(), cy.ravel()], -1))
    column = (dist <= tol).reshape(cx.shape)
    if column.sum() < 4:
        raise InvalidInput(f'heightfield_tet_mesh: footprint has {int(column.sum())} columns '
                           f'at h = {h * 1e3:.3g} mm; use a smaller h')
    gx, gy = np.meshgrid(xs, ys, indexing='ij')
    xy = np.stack([gx.ravel(), gy.ravel()], -1)
    # A scan is noisy: the top at a node is the Gaussian-weighted mean height of the points
    # within one element (nearest point where none), so the top has no sub-element bumps.
    dist, idx = cKDTree(heights[:, :2]).query(xy, k=min(32, len(heights)))
    weight = np.exp(-0.5 * (dist / (0.5 * h)) ** 2) * (dist <= h)
    weight[:, 0] = np.where(weight.sum(axis=1) > 0, weight[:, 0], 1.0)
    top = ((weight * heights[idx, 2]).sum(axis=1) / weight.sum(axis=1)).reshape(gx.shape)
    # Columns that thin out to the table make flat slivers that blow up under contact: the
    # body keeps at least ``min_top_fraction`` of its height (a short vertical side instead).
    top = np.maximum(top, min_top_fraction * top_height)
    frac = np.linspace(0.0, 1.0, nz_nodes)
    nodes = np.stack(np.broadcast_arrays(gx[..., None], gy[..., None],
                                         top[..., None] * frac), -1).reshape(-1, 3)
    keep = np.repeat(column[..., None], nz, axis=2)
    tets = _grid_tets((n_xy[0], n_xy[1], nz_nodes), keep)
    nodes, tets = _compact(nodes, tets)
    return TetMesh(nodes, _orient(nodes, tets), resolution=float(h))


def box_tet_mesh(size, centre, h: float) -> TetMesh:
    """Tet mesh of a box of ``size`` (3,) metres on the table, centred at ``centre`` (2,) x-y.

    Raises:
        InvalidInput: non-positive sizes or ``h``.

    """
    size = as_array(size, 'size', (3,))
    centre = as_array(centre, 'centre', (2,))
    if np.any(size <= 0) or not h > 0:
        raise InvalidInput('box_tet_mesh: size and h must be > 0')
    n = np.maximum(np.round(size / h).astype(int), 1) + 1
    axes = [np.linspace(-size[0] / 2, size[0] / 2, n[0]) + centre[0],
            np.linspace(-size[1] / 2, size[1] / 2, n[1]) + centre[1],
            np.linspace(0.0, size[2], n[2])]
    nodes = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3)
    tets = _grid_tets(tuple(n), np.ones(tuple(n - 1), dtype=bool))
    return TetMesh(nodes, _orient(nodes, tets), resolution=float(h))


def ball_tet_mesh(radius: float, h: float, centre=(0.0, 0.0)) -> TetMesh:
    """Tet mesh of a ball resting on the table (the seed paper's foam ball).

    A structured cube grid of spacing ``h`` is cut to the cells inside the ball and the
    boundary nodes are projected radially onto the sphere.

    Raises:
        InvalidInput: non-positive radius or ``h``, or ``h`` above the radius.

    """
    if not (radius > 0 and h > 0 and h < radius):
        raise InvalidInput(f'ball_tet_mesh: need 0 < h < radius, got h={h}, radius={radius}')
    n = 2 * int(np.ceil(radius / h)) + 1
    ax = np.linspace(-1.0, 1.0, n) * (n // 2) * h
    nodes = np.stack(np.meshgrid(ax, ax, ax, indexing='ij'), -1).reshape(-1, 3)
    cells = np.stack(np.meshgrid(0.5 * (ax[1:] + ax[:-1]), 0.5 * (ax[1:] + ax[:-1]),
                                 0.5 * (ax[1:] + ax[:-1]), indexing='ij'), -1)
    keep = np.linalg.norm(cells, axis=-1) <= radius - 0.2 * h
    tets = _grid_tets((n, n, n), keep)
    nodes, tets = _compact(nodes, tets)
    # boundary nodes: those on a face used by exactly one tet -> onto the sphere
    faces = np.sort(tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    boundary = np.unique(uniq[count == 1])
    r = np.linalg.norm(nodes[boundary], axis=1)
    nodes = nodes.copy()
    nodes[boundary] *= (radius / np.maximum(r, 1e-12))[:, None]
    nodes += np.array([centre[0], centre[1], radius])
    return TetMesh(nodes, _orient(nodes, tets), resolution=float(h))


def write_vtk(mesh: TetMesh, path) -> Path:
    """Write ``mesh`` as a legacy ASCII VTK unstructured grid (what PyBullet loads).

    Raises:
        DataError: the file cannot be written.

    """
    path = Path(path)
    lines = ['# vtk DataFile Version 2.0', 'pointforce replica tetrahedral mesh', 'ASCII',
             'DATASET UNSTRUCTURED_GRID', f'POINTS {len(mesh.nodes)} double']
    lines += [f'{x:.9g} {y:.9g} {z:.9g}' for x, y, z in mesh.nodes]
    lines.append(f'CELLS {len(mesh.tets)} {5 * len(mesh.tets)}')
    lines += [f'4 {a} {b} {c} {d}' for a, b, c, d in mesh.tets]
    lines.append(f'CELL_TYPES {len(mesh.tets)}')
    lines += ['10'] * len(mesh.tets)
    try:
        path.write_text('\n'.join(lines) + '\n')
    except OSError as exc:
        raise DataError(f'cannot write {path}: {exc}') from exc
    return path


def read_vtk(path, resolution: float) -> TetMesh:
    """Read a legacy ASCII VTK tet grid written by :func:`write_vtk`.

    Raises:
        DataError: missing file, or not an ASCII unstructured grid of tetrahedra.

    """
    path = Path(path)
    with reading(path, 'legacy ASCII VTK file (a binary VTK is not read)'):
        words = path.read_text(encoding=TEXT_ENCODING).split()
    try:
        i = words.index('POINTS')
        n = int(words[i + 1])
        nodes = np.array(words[i + 3:i + 3 + 3 * n], dtype=float).reshape(n, 3)
        j = words.index('CELLS')
        m = int(words[j + 1])
        cells = np.array(words[j + 3:j + 3 + 5 * m], dtype=np.int64).reshape(m, 5)
    except (ValueError, IndexError) as exc:
        raise DataError(f'{path}: not a legacy ASCII VTK tetrahedral grid: {exc}') from exc
    if np.any(cells[:, 0] != 4):
        raise DataError(f'{path}: only tetrahedral cells (4 nodes) are supported')
    try:
        return TetMesh(nodes, cells[:, 1:], resolution=resolution)
    except InvalidInput as exc:
        raise DataError(f'{path}: {exc}') from exc
