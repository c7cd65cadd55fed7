"""How a depth cloud of the deformed object is compared with the FEM's deformed surface.

The estimators use a point-to-plane error: each cloud point ``y_j`` is paired with the nearest
surface triangle of the *predicted* deformed surface (its projection inside the triangle, with
barycentric weights ``b``), and its residual is the distance along that triangle's normal,
``r_j = n_t . (y_j - sum_i b_i x_i(u))``. Linearised at the current prediction it is
affine in the node displacements, so with the FEM's linearity in the force (and in ``1/E``) the
fits become small linear least-squares problems, re-paired a few times as the prediction moves.
Why not the paper's two-way nearest-neighbour error (eq. 7): its nearest-neighbour distance is
blind to sliding along the surface, its gradient is piecewise and its value has a floor set by
the cloud's spacing and noise rather than by the misfit (so it is flat in nu, as the paper's
figure 3 shows). The point-to-plane distance measures exactly the surface motion a camera can
see (along the normal), is zero-mean under depth noise, and is smooth in the parameters. The
paper's eq. 7 is kept (:func:`two_way_nn_error`) for its Nelder-Mead baselines.

Points are dropped when they are on the table (``z < min_height``), inside the probe zone (closer
than ``exclusion_radius`` to the contact point's normal line: a probe hides most of it and the
linear point-load model is least right there), projecting farther than ``max_tangential``
outside every nearby triangle (not on the modelled surface) or farther than ``max_normal``
along the normal (outliers).
Lengths are metres, frame ``base``.
"""

from collections import deque
from dataclasses import dataclass
import threading
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.deformation.mesh import TetMesh, vertex_normals
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array


PROJECTION_CHUNK = 100_000
"""Points projected at once by :func:`rest_offsets` (bounds its memory to about 75 MB)."""


@dataclass(frozen=True)
class MatchConfig:
    """Point-to-plane pairing settings (metres).

    Attributes:
        exclusion_radius: cloud points closer than this to the contact normal line are unused.
        max_tangential: largest distance a point's projection may lie outside its triangle
            (default: set from the mesh, 0.25 element sizes, when 0).
        max_normal: largest normal residual kept (outliers beyond).
        min_height: points below this height are the table.
        max_points: the kept points are thinned to at most this many by a regular stride
            (depth pixels are correlated; more points cost time, not information).

    Raises:
        InvalidInput: negative values.

    """

    exclusion_radius: float = 0.012
    max_tangential: float = 0.0
    max_normal: float = 0.006
    min_height: float = 0.002
    max_points: int = 2000

    def __post_init__(self):
        for name in ('exclusion_radius', 'max_tangential', 'max_normal', 'min_height'):
            value = float(getattr(self, name))
            if not np.isfinite(value) or value < 0:
                raise InvalidInput(f'MatchConfig.{name}: must be finite and >= 0, got {value}')
        if int(self.max_points) < 20:
            raise InvalidInput(f'MatchConfig.max_points: need >= 20, got {self.max_points}')


@dataclass(frozen=True)
class Match:
    """Point-to-plane pairs of one cloud with the predicted surface.

    Attributes:
        nodes: (m, 3) node indices of each kept point's triangle.
        bary: (m, 3) barycentric weights of the point's projection on it.
        normal: (m, 3) unit normal of that triangle (predicted deformed surface).
        point: (m, 3) the kept cloud points, metres.
        gap: (m,) ``n . (y - sum b X)``: the normal offset from the rest surface, metres (the
            residual is ``gap - n . sum b u``).

    """

    nodes: np.ndarray
    bary: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    gap: np.ndarray


def check_cloud(cloud, name: str = 'cloud') -> np.ndarray:
    """Return a (P, 3) finite cloud or raise InvalidInput (empty, NaN, wrong shape)."""
    pts = as_array(cloud, name, (None, 3), finite=False)
    if len(pts) == 0:
        raise InvalidInput(f'{name}: empty point cloud')
    if not np.all(np.isfinite(pts)):
        raise InvalidInput(f'{name}: {int(np.sum(~np.isfinite(pts).all(axis=1)))} point(s) '
                           f'hold NaN or inf; drop invalid pixels first')
    return pts


class SurfaceMatcher:
    """Pairs one cloud with the mesh surface, excluding the probe zone around a contact.

    Args:
        mesh: the volume mesh.
        contact_point: (3,) contact point, metres, ``base``.
        cloud: (P, 3) deformed cloud, metres, ``base``.
        config: pairing settings.
        min_points: fewest kept points before the cloud is called unusable.
        rest_offset: optional (N,) normal offset of the equilibrium cloud from each rest node
            (:func:`rest_offsets`), metres, subtracted from every gap so that the residual
            measures displacement from the scanned rest shape, not the mesh's own
            discretisation of it.

    Raises:
        InvalidInput: empty or non-finite cloud, or fewer than ``min_points`` usable points.

    """

    def __init__(self, mesh: TetMesh, contact_point, cloud, config: MatchConfig = MatchConfig(),
                 min_points: int = 20, rest_offset=None):
        self.mesh = mesh
        self.rest_offset = (np.zeros(mesh.n_nodes) if rest_offset is None
                            else as_array(rest_offset, 'rest_offset', (mesh.n_nodes,)))
        self.config = config
        self.min_points = int(min_points)
        pts = check_cloud(cloud)
        c = as_array(contact_point, 'contact point', (3,))
        surf = mesh.surface_nodes
        normals = vertex_normals(mesh.nodes, mesh.surface_triangles)
        k = surf[np.argmin(np.linalg.norm(mesh.nodes[surf] - c, axis=1))]
        axis = normals[k]
        rel = pts - c
        lateral = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
        keep = (pts[:, 2] >= config.min_height) & (lateral >= config.exclusion_radius)
        pts = pts[keep]
        stride = int(np.ceil(len(pts) / int(config.max_points)))
        self.points = pts[::max(stride, 1)]
        self.max_tangential = config.max_tangential or 0.25 * mesh.element_size
        if len(self.points) < self.min_points:
            raise InvalidInput(f'cloud: only {len(self.points)} points above the table and '
                               f'outside the probe zone; need {self.min_points}')

    def match(self, u=None) -> Match:
        """Pair the cloud with the surface displaced by ``u`` (ndof,) metres (default rest).

        Raises:
            InvalidInput: fewer than ``min_points`` points pair with the surface.

        """
        x = self.mesh.nodes if u is None else self.mesh.nodes + np.reshape(u, (-1, 3))
        tri, bary, n, dn, outside = project_on_triangles(x, self.mesh.surface_triangles,
                                                         self.points)
        ok = (outside <= self.max_tangential) & (np.abs(dn) <= self.config.max_normal)
        if int(ok.sum()) < self.min_points:
            raise InvalidInput(f'cloud: only {int(ok.sum())} points lie on the modelled surface '
                               f'(within {self.max_tangential * 1e3:.1f} mm of a triangle and '
                               f'{self.config.max_normal * 1e3:.1f} mm across); need '
                               f'{self.min_points}')
        nodes = self.mesh.surface_triangles[tri[ok]]
        b, n, pts = bary[ok], n[ok], self.points[ok]
        rest = np.einsum('mi,mij->mj', b, self.mesh.nodes[nodes])
        offset = np.einsum('mi,mi->m', b, self.rest_offset[nodes])
        gap = np.einsum('ij,ij->i', pts - rest, n) - offset
        return Match(nodes=nodes, bary=b, normal=n, point=pts, gap=gap)


def project_on_triangles(positions: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                         candidates: int = 4):
    """Project points on the nearest of the triangles whose centroids are nearest.

    Args:
        positions: (N, 3) node positions, metres.
        triangles: (T, 3) node indices, outward winding.
        points: (P, 3) points, metres.
        candidates: triangles (by centroid distance) tried per point.

    Returns:
        ``(tri (P,), bary (P, 3), normal (P, 3), normal offset (P,) m, outside (P,) m)``:
        the chosen triangle, the barycentric weights of the point's projection on its plane,
        the triangle's unit normal, the signed distance along it, and how far the projection
        lies outside the triangle (0 inside).

    """
    c = positions[triangles]  # (T, 3, 3)
    centroid = c.mean(axis=1)
    k = min(int(candidates), len(triangles))
    _, cand = cKDTree(centroid).query(points, k=k)
    cand = cand.reshape(len(points), k)
    e1 = c[:, 1] - c[:, 0]
    e2 = c[:, 2] - c[:, 0]
    nrm = np.cross(e1, e2)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    # barycentric solve in each candidate's plane (Gram matrix of the edges)
    d = points[:, None, :] - c[cand, 0]  # (P, k, 3)
    a11 = np.einsum('ij,ij->i', e1, e1)[cand]
    a12 = np.einsum('ij,ij->i', e1, e2)[cand]
    a22 = np.einsum('ij,ij->i', e2, e2)[cand]
    r1 = np.einsum('pkj,pkj->pk', d, e1[cand])
    r2 = np.einsum('pkj,pkj->pk', d, e2[cand])
    det = a11 * a22 - a12 * a12
    b1 = (a22 * r1 - a12 * r2) / det
    b2 = (a11 * r2 - a12 * r1) / det
    b0 = 1.0 - b1 - b2
    bary = np.stack([b0, b1, b2], axis=-1)  # (P, k, 3)
    scale = np.sqrt(np.maximum(a11, a22))
    outside = np.clip(-bary, 0.0, None).max(axis=-1) * scale
    dn = np.einsum('pkj,pkj->pk', d, nrm[cand])
    score = np.hypot(dn, outside)
    best = np.argmin(score, axis=1)
    rows = np.arange(len(points))
    tri = cand[rows, best]
    return tri, bary[rows, best], nrm[tri], dn[rows, best], outside[rows, best]


def rest_offsets(mesh: TetMesh, rest_cloud, config: MatchConfig = MatchConfig(),
                 min_count: float = 3.0) -> np.ndarray:
    """(N,) mean normal offset of the equilibrium cloud from each rest surface node, metres.

    The mesh is a discretisation of the scanned surface (a height field averaged over
    neighbours, a footprint snapped to the grid), so at rest it sits a fraction of a millimetre
    off the cloud in places (measured: 0.3 mm inside on the sides of a box). The force fit
    would explain such a fixed gap with a force; subtracting it makes the residual a
    difference between two scans, as the paper's registration to the rest mesh does. Each
    paired point's offset is shared among its triangle's nodes by barycentric weight; nodes
    with less than ``min_count`` total weight get 0.

    Raises:
        InvalidInput: empty or non-finite cloud.

    """
    pts = check_cloud(rest_cloud, 'rest cloud')
    pts = pts[pts[:, 2] >= config.min_height]
    total = np.zeros(mesh.n_nodes)
    count = np.zeros(mesh.n_nodes)
    # in chunks: the projection holds ~0.75 kB per point (1.2 GB for four 400k-point rest
    # frames of a depth camera at once); the sums are the same
    for start in range(0, len(pts), PROJECTION_CHUNK):
        tri, bary, _, dn, outside = project_on_triangles(
            mesh.nodes, mesh.surface_triangles, pts[start:start + PROJECTION_CHUNK])
        ok = (outside <= (config.max_tangential or 0.25 * mesh.element_size)) & (
            np.abs(dn) <= config.max_normal)
        nodes = mesh.surface_triangles[tri[ok]].ravel()
        w = bary[ok].clip(0.0, 1.0).ravel()
        total += np.bincount(nodes, w * np.repeat(dn[ok], 3), minlength=mesh.n_nodes)
        count += np.bincount(nodes, w, minlength=mesh.n_nodes)
    return np.where(count >= min_count, total / np.maximum(count, 1e-12), 0.0)


class RestFrames:
    """The pushing camera's own rest frames: the reference a push's residual is measured from.

    A depth bias moves each view's points along that view's rays, so the merged multi-view scan
    the mesh is built from does not cancel the bias of the camera that films the pushes; a
    rest frame of that same camera does (measured on the foam block with a 2 mm bias, node
    defaults, 3 held-out sites x 3, 5, 8 mm: 16.0 % mean magnitude error from the merged scan,
    4.6 % from 4 rest frames; ``test/nodes/test_deformation_force_node.py``). Frames are
    offered while no push runs (:meth:`add`, newest ``count`` kept) and become the reference
    when the next push starts
    (:meth:`freeze`), so that a frame taken during a push never enters it; a push with no new
    rest frame before it keeps the previous reference. Thread-safe (the offsets are computed
    outside the lock).

    Args:
        count: rest frames stacked (newest kept); 0 keeps none (the merged scan is used).

    Raises:
        InvalidInput: a negative count.

    """

    def __init__(self, count: int = 4):
        if int(count) < 0:
            raise InvalidInput(f'RestFrames.count: need >= 0, got {count}')
        self.count = int(count)
        self._lock = threading.Lock()
        self._pending = deque(maxlen=max(self.count, 1))
        self._frames: Optional[np.ndarray] = None
        self._frozen = 0
        self._cache = None  # (frames, mesh, offsets) of the frozen reference

    @property
    def frames(self) -> Optional[np.ndarray]:
        """(R, 3) the frozen reference (stacked frames, metres, ``base``), or None."""
        return self._frames

    @property
    def frozen(self) -> int:
        """How many frames the frozen reference stacks (0: none)."""
        return self._frozen

    @property
    def pending(self) -> int:
        """Rest frames offered since the last :meth:`freeze`."""
        return len(self._pending)

    def add(self, points) -> None:
        """Offer one rest frame (P, 3) metres ``base``, taken while no push runs."""
        if self.count and len(points):
            with self._lock:
                self._pending.append(np.asarray(points, dtype=float))

    def freeze(self) -> bool:
        """Make the pending rest frames the reference, as a push starts (True if any)."""
        with self._lock:
            if not self._pending:
                return False
            self._frames = np.concatenate(list(self._pending))
            self._frozen = len(self._pending)
            self._pending.clear()
            return True

    def clear(self) -> None:
        """Forget every frame (the camera moved, or the object changed)."""
        with self._lock:
            self._pending.clear()
            self._frames, self._frozen, self._cache = None, 0, None

    def offsets(self, mesh: TetMesh, config: Optional[MatchConfig] = None
                ) -> Optional[np.ndarray]:
        """(N,) :func:`rest_offsets` of the frozen reference on ``mesh``, or None (no frame).

        Cached per mesh and reference.

        Raises:
            InvalidInput: as :func:`rest_offsets`.

        """
        with self._lock:
            frames, cache = self._frames, self._cache
        if frames is None:
            return None
        if cache is not None and cache[0] is frames and cache[1] is mesh:
            return cache[2]
        offset = rest_offsets(mesh, frames, config or MatchConfig())
        with self._lock:
            if self._frames is frames:
                self._cache = (frames, mesh, offset)
        return offset


def normal_rows(match: Match, columns: np.ndarray) -> np.ndarray:
    """(m, k) rows ``n_j^T sum_i b_i U_i`` of displacement columns (ndof, k) at the pairs."""
    cols = np.asarray(columns).reshape(-1, 3, columns.shape[1])[match.nodes]  # (m, 3, 3, k)
    return np.einsum('mi,mn,mnik->mk', match.normal, match.bary, cols)


def normal_of(match: Match, u: np.ndarray) -> np.ndarray:
    """(m,) ``n_j . sum_i b_i u_i`` of one displacement field ``u`` (ndof,), metres."""
    un = np.reshape(u, (-1, 3))[match.nodes]  # (m, 3, 3)
    return np.einsum('mi,mn,mni->m', match.normal, match.bary, un)


def visible_nodes(mesh: TetMesh, matcher: SurfaceMatcher) -> np.ndarray:
    """Surface nodes with a kept cloud point within one element size at rest (eq. 7's X_V)."""
    surf = mesh.surface_nodes
    d, _ = cKDTree(matcher.points).query(mesh.nodes[surf])
    return surf[d <= mesh.element_size]


def two_way_nn_error(positions: np.ndarray, nodes: np.ndarray, cloud: np.ndarray) -> float:
    """Seed 001's eq. 7: mean squared node-to-cloud plus cloud-to-node NN distance, m^2.

    Args:
        positions: (N, 3) deformed node positions of the model, metres.
        nodes: (V,) indices of the visible surface nodes ``X_V``.
        cloud: (P, 3) observed points ``Y``, metres.

    """
    xv = positions[nodes]
    d1, _ = cKDTree(cloud).query(xv)
    d2, _ = cKDTree(xv).query(cloud)
    return float(np.mean(d1 ** 2) + np.mean(d2 ** 2))
