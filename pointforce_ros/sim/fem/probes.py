"""Rigid probe meshes (``types.Mesh`` in the probe's own frame) and probe poses.

Convention for every probe: the probe frame's +z axis is the push direction (the UR TCP z axis),
the probe's working end is at the origin and its body extends towards -z. All sizes in metres.
Probes are closed, convex, counter-clockwise (outward) triangle meshes.
"""

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh, Pose
from pointforce_ros.rotations import matrix_to_quaternion


def revolve(radius: np.ndarray, z: np.ndarray, segments: int = 48) -> Mesh:
    """Build a closed surface of revolution about the z axis.

    Args:
        radius: (K,) profile radii, metres, ``radius[0] == radius[-1] == 0`` (the poles).
        z: (K,) profile heights, metres, monotone from one pole to the other.
        segments: number of divisions around the axis.

    Raises:
        InvalidInput: profile without poles or of fewer than three points.

    """
    radius = np.asarray(radius, dtype=float)
    z = np.asarray(z, dtype=float)
    if len(radius) < 3 or radius[0] != 0 or radius[-1] != 0 or len(z) != len(radius):
        raise InvalidInput('revolve: profile needs >= 3 points starting and ending on the axis')
    theta = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring_r = radius[1:-1]
    ring = np.stack([ring_r[:, None] * np.cos(theta), ring_r[:, None] * np.sin(theta),
                     np.broadcast_to(z[1:-1, None], (len(ring_r), segments))], -1)
    verts = np.concatenate([[[0.0, 0.0, z[0]]], ring.reshape(-1, 3), [[0.0, 0.0, z[-1]]]])
    n_ring = len(ring_r)
    top = len(verts) - 1
    j = np.arange(segments)
    jn = (j + 1) % segments
    tris = [np.stack([np.zeros(segments, int), 1 + jn, 1 + j], -1)]
    for r in range(n_ring - 1):
        a, b = 1 + r * segments + j, 1 + r * segments + jn
        c, d = a + segments, b + segments
        tris += [np.stack([a, b, d], -1), np.stack([a, d, c], -1)]
    base = 1 + (n_ring - 1) * segments
    tris.append(np.stack([np.full(segments, top), base + j, base + jn], -1))
    tris = np.concatenate(tris)
    return _outward(Mesh(verts, tris))


def _outward(mesh: Mesh) -> Mesh:
    """Flip the winding when the signed volume is negative (so normals point outward)."""
    v = mesh.vertices[mesh.triangles]
    vol = np.einsum('ij,ij->i', v[:, 0], np.cross(v[:, 1], v[:, 2])).sum()
    if vol < 0:
        return Mesh(mesh.vertices, mesh.triangles[:, ::-1])
    return mesh


def _arc(r, cz, a0, a1, n):
    ang = np.linspace(a0, a1, n)
    return r * np.sin(ang), cz - r * np.cos(ang)


def point_probe(tip_radius: float = 0.0015, half_angle_deg: float = 15.0,
                length: float = 0.03, segments: int = 48) -> Mesh:
    """Tapered point probe: a cone of half-angle ``half_angle_deg`` with a spherical tip.

    The push direction is +z: the tip's leading point is the origin and the cone opens
    towards -z, closed by a flat cap at ``z = -length``.
    """
    if tip_radius <= 0 or not 0 < half_angle_deg < 80 or length <= 2 * tip_radius:
        raise InvalidInput('point_probe: need tip_radius > 0, 0 < half_angle < 80 deg, '
                           'length > 2 tip_radius')
    alpha = np.radians(half_angle_deg)
    # Tip sphere centre at z = -tip_radius; the cone is tangent at polar angle 90 deg - alpha.
    r_a, z_a = _arc(tip_radius, tip_radius, 0.0, np.pi / 2 - alpha, 10)
    z_a = -z_a
    r_top = r_a[-1] + (length - (-z_a[-1])) * np.tan(alpha)
    radius = np.concatenate([r_a, [r_top, 0.0]])
    z = np.concatenate([z_a, [-length, -length]])
    return revolve(radius, z, segments)


def sphere_probe(radius: float = 0.01, rings: int = 48, segments: int = 64) -> Mesh:
    """Sphere of ``radius`` whose lowest point (in push direction +z) is the origin."""
    if radius <= 0:
        raise InvalidInput('sphere_probe: radius must be positive')
    ang = np.linspace(0.0, np.pi, rings + 1)
    r = radius * np.sin(ang)
    r[[0, -1]] = 0.0
    return revolve(r, -radius + radius * np.cos(ang), segments)


def rounded_box(half_extents, edge_radius: float, cells: int = 6) -> Mesh:
    """Box with every edge and corner rounded to ``edge_radius``, centred at the origin.

    Args:
        half_extents: (3,) half sizes of the outer box, metres (each > ``edge_radius``).
        edge_radius: fillet radius, metres.
        cells: grid cells per fillet quarter arc (the flat parts get proportionally more).

    """
    h = np.asarray(half_extents, dtype=float)
    if h.shape != (3,) or np.any(h <= edge_radius) or edge_radius <= 0:
        raise InvalidInput('rounded_box: need 3 half extents, each > edge_radius > 0')
    inner = h - edge_radius

    def axis(k):
        band = edge_radius * np.tan(np.linspace(0, np.pi / 4, cells + 1))
        spacing = max(edge_radius * np.pi / 2 / cells, 0.002)
        flat_n = max(1, int(np.ceil(2 * inner[k] / spacing)))
        mid = np.linspace(-inner[k], inner[k], flat_n + 1)
        return np.concatenate([-inner[k] - band[::-1], mid[1:-1], inner[k] + band])

    verts, tris = [], []
    offset = 0
    for k in range(3):
        for sign in (-1.0, 1.0):
            a, b = [o for o in range(3) if o != k]
            ua, ub = axis(a), axis(b)
            ga, gb = np.meshgrid(ua, ub, indexing='ij')
            p = np.zeros(ga.shape + (3,))
            p[..., a], p[..., b], p[..., k] = ga, gb, sign * h[k]
            na, nb = ga.shape
            idx = offset + np.arange(na * nb).reshape(na, nb)
            q = [idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]]
            t = np.concatenate([np.stack([q[0], q[1], q[2]], -1).reshape(-1, 3),
                                np.stack([q[0], q[2], q[3]], -1).reshape(-1, 3)])
            # (a, b, k) right-handed iff cyclic order; flip for the negative face.
            cyclic = (b - a) % 3 == 1
            if (sign > 0) != cyclic:
                t = t[:, ::-1]
            verts.append(p.reshape(-1, 3))
            tris.append(t)
            offset += na * nb
    v = np.concatenate(verts)
    c = np.clip(v, -inner, inner)
    d = v - c
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    v = c + edge_radius * d / np.where(norm > 0, norm, 1.0)
    v, inv = np.unique(np.round(v, 12), axis=0, return_inverse=True)
    t = inv.ravel()[np.concatenate(tris)]
    keep = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2])
    return Mesh(v, t[keep])


def paddle_probe(length: float = 0.06, thickness: float = 0.006, height: float = 0.03,
                 edge_radius: float = 0.0025) -> Mesh:
    """Line paddle: a thin rounded box, long axis along x, pressing edge at z = 0."""
    mesh = rounded_box([length / 2, thickness / 2, height / 2], edge_radius)
    return Mesh(mesh.vertices - [0.0, 0.0, height / 2], mesh.triangles)


def box_probe(size=(0.03, 0.03, 0.02), edge_radius: float = 0.002) -> Mesh:
    """Box with rounded edges, bottom face (in push direction) at z = 0."""
    half = np.asarray(size, dtype=float) / 2
    mesh = rounded_box(half, edge_radius)
    return Mesh(mesh.vertices - [0.0, 0.0, half[2]], mesh.triangles)


def cylinder_probe(radius: float = 0.01, length: float = 0.06, rim_radius: float = 0.002,
                   segments: int = 64) -> Mesh:
    """Cylinder lying sideways (axis along x) with filleted rims; lowest line at z = 0."""
    if radius <= rim_radius or length <= 2 * rim_radius:
        raise InvalidInput('cylinder_probe: need radius > rim_radius and length > 2 rim_radius')
    half = length / 2
    fr, fz = _arc(rim_radius, 0.0, 0.0, np.pi / 2, 8)
    r = np.concatenate([[0.0], radius - rim_radius + fr, (radius - rim_radius + fr)[::-1],
                        [0.0]])
    z = np.concatenate([[-half], -half + rim_radius + fz, half - rim_radius - fz[::-1], [half]])
    mesh = revolve(r, z, segments)
    v = mesh.vertices[:, [2, 1, 0]] * [1.0, 1.0, -1.0]  # axis z -> x (proper rotation)
    v = v - [0.0, 0.0, radius]
    return _outward(Mesh(v, mesh.triangles))


def pose_for_push(position, push_direction, roll: float = 0.0) -> Pose:
    """Pose whose +z axis is ``push_direction`` (3,) and whose origin is ``position`` (3,), m.

    ``roll`` (rad) rotates the probe about the push direction.

    Raises:
        InvalidInput: zero-length direction.

    """
    zdir = np.asarray(push_direction, dtype=float)
    n = np.linalg.norm(zdir)
    if not n > 0:
        raise InvalidInput('pose_for_push: push_direction must be non-zero')
    zdir = zdir / n
    ref = np.array([1.0, 0.0, 0.0]) if abs(zdir[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    xdir = ref - zdir * (ref @ zdir)
    xdir /= np.linalg.norm(xdir)
    ydir = np.cross(zdir, xdir)
    c, s = np.cos(roll), np.sin(roll)
    xdir, ydir = c * xdir + s * ydir, -s * xdir + c * ydir
    return Pose(np.asarray(position, dtype=float),
                matrix_to_quaternion(np.stack([xdir, ydir, zdir], 1)))
