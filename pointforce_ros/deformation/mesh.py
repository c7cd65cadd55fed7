"""Tetrahedral volume mesh of a scanned object lying on the table, from its equilibrium surface.

Why a structured extrusion and not a Delaunay/TetWild mesher: the object rests on a flat table
(``z = 0`` in ``base``) and the camera sees it from above, so the equilibrium surface is a height
field ``z = h(x, y)`` over a footprint. Closing it down to the table along vertical columns gives
a watertight volume by construction (no surface repair, no hole filling of the unseen bottom,
which a surface mesher would need), a mesh whose size and grading are set by two numbers
(element size in x-y, number of layers graded finer towards the top where the probe pushes), a
bottom layer of nodes exactly on the table to fix, and no new dependency (numpy/scipy only).
The price: undercuts and overhangs are not represented (a height field has none), and a curved
footprint outline is staircased at the element size. For objects lying on a table (the cell's
objects, the seed's stuffed toy) that is the right trade; a mesher from PyPI (``pytetwild``,
``tetgen``) remains the way for an object with overhangs.

Each footprint cell and layer is a hexahedron split into 6 tetrahedra around its main diagonal
(the Kuhn/Freudenthal split); every hexahedron is split the same way, so the tetrahedra are
conforming across cells. All coordinates are metres in ``base``.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array

KUHN_TETS = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6],
                      [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])
"""(6, 4) tetrahedra of a hexahedron (nodes 0-3 bottom counter-clockwise, 4-7 top) around 0-6."""
MAX_MESH_NODES = 25_000
"""Most nodes a mesh from a surface may have (counted over the grid of its x-y bounding box).

The FEM factorises its stiffness once per mesh: measured on this machine kind (block meshes,
element 4 mm, 6 layers), 4.7k nodes 2.1 s / 0.4 GB, 18k nodes 26 s / 1.4 GB, 40k nodes over
200 s. The cell's objects (at most 0.10 x 0.075 m) need 4k nodes at the defaults and 14k at
2 mm. Without the bound one stray point 20 m from a surface on ``cloud_capture/surface`` made
the node allocate 3.9 GB and work for 58 s."""


@dataclass(frozen=True)
class TetMesh:
    """Linear tetrahedral mesh of an object on the table.

    Attributes:
        nodes: (N, 3) rest node positions, metres, ``base``.
        tets: (M, 4) node indices, positively oriented (positive signed volume).
        fixed_nodes: (F,) indices of the nodes on the table (clamped in the FEM).
        surface_triangles: (T, 3) node indices of the boundary faces that are not on the table
            (what a camera can see), wound counter-clockwise seen from outside.
        element_size: nominal edge length in x-y, metres.

    """

    nodes: np.ndarray
    tets: np.ndarray
    fixed_nodes: np.ndarray
    surface_triangles: np.ndarray
    element_size: float

    @property
    def n_nodes(self) -> int:
        """Return the number of nodes."""
        return len(self.nodes)

    @property
    def surface_nodes(self) -> np.ndarray:
        """(S,) sorted unique node indices of the surface triangles."""
        return np.unique(self.surface_triangles)

    def volumes(self, positions: Optional[np.ndarray] = None) -> np.ndarray:
        """(M,) signed tetrahedron volumes, m^3, at ``positions`` (N, 3) (default rest)."""
        x = self.nodes if positions is None else positions
        p = x[self.tets]
        return np.einsum('ij,ij->i', p[:, 1] - p[:, 0],
                         np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])) / 6.0


def vertex_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted unit vertex normals of a triangle surface (zero off the surface).

    Args:
        positions: (N, 3) node positions, metres.
        triangles: (T, 3) node indices, outward winding.

    """
    c = positions[triangles]
    fn = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])  # 2 x area x unit normal
    idx = triangles.ravel()
    acc = np.stack([np.bincount(idx, np.repeat(fn[:, c], 3), minlength=len(positions))
                    for c in range(3)], axis=1)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def crease_nodes(positions: np.ndarray, triangles: np.ndarray,
                 max_angle_deg: float = 30.0) -> np.ndarray:
    """Boolean (N,) nodes where adjacent surface triangles differ by more than the angle.

    A vertex normal there (a box edge or corner) is not the normal of either face, so a
    point-to-plane residual through it would be wrong; observations use non-crease nodes.
    """
    c = positions[triangles]
    fn = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    vn = vertex_normals(positions, triangles)
    cos = np.einsum('ij,ij->i', np.repeat(fn, 3, axis=0), vn[triangles.ravel()])
    worst = np.ones(len(positions))
    np.minimum.at(worst, triangles.ravel(), cos)
    return worst < np.cos(np.radians(max_angle_deg))


def graded_layers(layers: int, grading: float) -> np.ndarray:
    """(layers + 1,) fractions of the height from 0 (table) to 1 (top), finer at the top.

    ``zeta_k = 1 - (1 - k / layers) ** grading``; ``grading = 1`` is uniform.

    Raises:
        InvalidInput: fewer than one layer or grading below 1.

    """
    if int(layers) < 1 or not grading >= 1.0:
        raise InvalidInput(f'graded_layers: need layers >= 1 and grading >= 1, got {layers}, '
                           f'{grading}')
    t = np.arange(int(layers) + 1) / int(layers)
    return 1.0 - (1.0 - t) ** float(grading)


def extrude_height_field(x: np.ndarray, y: np.ndarray, height: np.ndarray,
                         cells: np.ndarray, layers: int = 6, grading: float = 1.5) -> TetMesh:
    """Close a height field down to the table and split it into tetrahedra.

    Args:
        x: (nx + 1,) increasing grid node coordinates, metres.
        y: (ny + 1,) increasing grid node coordinates, metres.
        height: (nx + 1, ny + 1) top height above the table at the grid nodes, metres (> 0
            wherever a node belongs to an active cell).
        cells: (nx, ny) boolean mask of the footprint cells to mesh.
        layers: element layers through the height.
        grading: layer grading (:func:`graded_layers`).

    Returns:
        TetMesh with only the nodes of active cells; bottom nodes fixed.

    Raises:
        InvalidInput: mismatched shapes, no active cell, or a non-positive height under one.

    """
    x = as_array(x, 'x', (None,))
    y = as_array(y, 'y', (None,))
    nx, ny = len(x) - 1, len(y) - 1
    height = as_array(height, 'height', (nx + 1, ny + 1))
    cells = np.asarray(cells, dtype=bool)
    if cells.shape != (nx, ny) or not cells.any():
        raise InvalidInput(f'extrude_height_field: cells must be a ({nx}, {ny}) mask with at '
                           f'least one active cell')
    if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0):
        raise InvalidInput('extrude_height_field: grid coordinates must increase')
    used = np.zeros((nx + 1, ny + 1), dtype=bool)
    ci, cj = np.nonzero(cells)
    for di in (0, 1):
        for dj in (0, 1):
            used[ci + di, cj + dj] = True
    if np.any(height[used] <= 0):
        raise InvalidInput('extrude_height_field: the height must be positive over the footprint')
    zeta = graded_layers(layers, grading)
    nz = len(zeta) - 1
    col = -np.ones((nx + 1, ny + 1), dtype=int)
    col[used] = np.arange(int(used.sum()))
    ncol = int(used.sum())
    ii, jj = np.nonzero(used)
    xy = np.stack([x[ii], y[jj]], -1)
    nodes = np.concatenate([np.column_stack([xy, zeta[k] * height[ii, jj]])
                            for k in range(nz + 1)])
    # hexahedra: bottom face counter-clockwise seen from above, then the top face
    c00, c10, c11, c01 = col[ci, cj], col[ci + 1, cj], col[ci + 1, cj + 1], col[ci, cj + 1]
    base = np.stack([c00, c10, c11, c01], -1)  # (C, 4)
    hexes = np.concatenate([np.concatenate([base + k * ncol, base + (k + 1) * ncol], -1)
                            for k in range(nz)])
    tets = hexes[:, KUHN_TETS].reshape(-1, 4)
    p = nodes[tets]
    vol = np.einsum('ij,ij->i', p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]))
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    surface = _boundary_triangles(nodes, tets)
    on_table = np.all(surface < ncol, axis=1)
    h = float(min(np.diff(x).mean(), np.diff(y).mean()))
    return TetMesh(nodes=nodes, tets=tets, fixed_nodes=np.arange(ncol),
                   surface_triangles=surface[~on_table], element_size=h)


def _boundary_triangles(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(B, 3) faces used by exactly one tetrahedron, wound outward."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]],
                            tets[:, [0, 2, 1]]])
    opposite = np.concatenate([tets[:, 0], tets[:, 1], tets[:, 2], tets[:, 3]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = counts[inv.ravel()] == 1
    faces, opposite = faces[once], opposite[once]
    c = nodes[faces]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    inward = np.einsum('ij,ij->i', n, nodes[opposite] - c[:, 0]) > 0
    faces[inward] = faces[inward][:, [0, 2, 1]]
    return faces


def block_mesh(size, element_size: float, layers: int, grading: float = 1.0,
               corner=(0.0, 0.0)) -> TetMesh:
    """Tetrahedral mesh of a rectangular block ``size`` (3,) metres on the table at ``corner``.

    Raises:
        InvalidInput: non-positive size or element size.

    """
    size = as_array(size, 'size', (3,))
    if np.any(size <= 0) or not element_size > 0:
        raise InvalidInput('block_mesh: size and element_size must be positive')
    nx = max(1, int(round(size[0] / element_size)))
    ny = max(1, int(round(size[1] / element_size)))
    x = corner[0] + np.linspace(0.0, size[0], nx + 1)
    y = corner[1] + np.linspace(0.0, size[1], ny + 1)
    return extrude_height_field(x, y, np.full((nx + 1, ny + 1), size[2]),
                                np.ones((nx, ny), dtype=bool), layers, grading)


def volume_mesh_from_surface(points, normals=None, element_size: float = 0.004,
                             layers: int = 6, grading: float = 1.5,
                             neighbours: int = 12, min_height: float = 0.002) -> TetMesh:
    """Volume mesh of an object on the table from its equilibrium surface cloud.

    The footprint is the set of grid cells (``element_size`` apart over the cloud's x-y
    bounding box) that points project into, closed morphologically and with holes filled. The
    top height at each grid node is the mean ``z`` of the ``neighbours`` nearest upward-facing
    points (``normal_z > 0.5`` when ``normals`` are given; all points above ``min_height``
    otherwise), which averages the depth noise down.

    Args:
        points: (P, 3) equilibrium surface points, metres, ``base`` (table at ``z = 0``).
        normals: optional (P, 3) outward unit normals.
        element_size: x-y element size, metres.
        layers, grading: through-height layers (:func:`graded_layers`).
        neighbours: points averaged per height sample.
        min_height: points lower than this (the table, its edge) are ignored, metres.

    Raises:
        InvalidInput: bad shapes, NaN, too few points above the table, bad sizes, or a
            bounding box that would need more than :data:`MAX_MESH_NODES` nodes (checked
            before anything is allocated).

    """
    pts = as_array(points, 'points', (None, 3))
    if not element_size > 0:
        raise InvalidInput(f'volume_mesh_from_surface: element_size must be positive, got '
                           f'{element_size}')
    if int(layers) < 1:
        raise InvalidInput(f'volume_mesh_from_surface: need layers >= 1, got {layers}')
    above = pts[:, 2] > min_height
    top = above.copy()
    if normals is not None:
        nrm = as_array(normals, 'normals', pts.shape)
        top &= nrm[:, 2] > 0.5
    if int(top.sum()) < max(20, neighbours):
        raise InvalidInput(f'volume_mesh_from_surface: only {int(top.sum())} upward points '
                           f'above {min_height} m; need at least {max(20, neighbours)}')
    body = pts[above]
    lo, hi = body[:, :2].min(axis=0), body[:, :2].max(axis=0)
    with np.errstate(over='ignore'):   # floats: a far point gives inf, not an int overflow
        spans = np.maximum(1.0, np.round((hi - lo) / element_size))
        nodes = float(np.prod(spans + 1.0)) * (int(layers) + 1)
    if not nodes <= MAX_MESH_NODES:
        raise InvalidInput(f'volume_mesh_from_surface: the surface spans '
                           f'{(hi - lo)[0]:.3g} x {(hi - lo)[1]:.3g} m above the table, a mesh '
                           f'of up to {nodes:.3g} nodes at element_size {element_size:g} m and '
                           f'{int(layers)} layers (limit {MAX_MESH_NODES}): crop the surface '
                           f'to the object (a stray point?), or raise element_size or lower '
                           f'layers')
    n_cells = spans.astype(int)
    x = np.linspace(lo[0], hi[0], n_cells[0] + 1)
    y = np.linspace(lo[1], hi[1], n_cells[1] + 1)
    ix = np.clip(((body[:, 0] - lo[0]) / (hi[0] - lo[0]) * n_cells[0]).astype(int), 0,
                 n_cells[0] - 1)
    iy = np.clip(((body[:, 1] - lo[1]) / (hi[1] - lo[1]) * n_cells[1]).astype(int), 0,
                 n_cells[1] - 1)
    cells = np.zeros(tuple(n_cells), dtype=bool)
    cells[ix, iy] = True
    cells = ndimage.binary_fill_holes(ndimage.binary_closing(cells, iterations=1,
                                                             border_value=0) | cells)
    gx, gy = np.meshgrid(x, y, indexing='ij')
    tops = pts[top]
    _, idx = cKDTree(tops[:, :2]).query(np.column_stack([gx.ravel(), gy.ravel()]),
                                        k=int(neighbours))
    height = tops[idx, 2].mean(axis=1).reshape(gx.shape)
    return extrude_height_field(x, y, height, cells, layers, grading)
