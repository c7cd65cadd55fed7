"""Rigid triangle meshes of planner objects (sphere, box, cylinder) in their own frame.

Metres, outward counter-clockwise triangles. The robot's probes (point probe, line paddle,
cylinder) are in :mod:`pointforce_ros.sim.fem.probes`, in the UR tool convention (+z = push
direction, working end at the origin).
"""

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh


def _positive(name, value):
    if not np.isfinite(value) or value <= 0:
        raise InvalidInput(f'{name}: must be a positive length in metres, got {value}')
    return float(value)


def _convex_mesh(vertices, triangles) -> Mesh:
    """Mesh of a convex solid with every triangle turned to face away from the centroid."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    tri = v[t]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = np.einsum('ij,ij->i', normal, tri.mean(axis=1) - v.mean(axis=0)) < 0
    t[inward] = t[inward][:, ::-1]
    return Mesh(vertices=v, triangles=t)


def icosphere(radius: float = 0.02, subdivisions: int = 2) -> Mesh:
    """Sphere of ``radius`` (m) centred at the origin; 2 subdivisions give 162 vertices."""
    radius = _positive('radius', radius)
    t = (1.0 + 5 ** 0.5) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in verts]
    for _ in range(int(subdivisions)):
        cache = {}
        new_faces = []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[key] = len(v) - 1
            return cache[key]
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return _convex_mesh(np.array(v) * radius, np.array(faces))


def box(size=(0.02, 0.02, 0.02)) -> Mesh:
    """Axis-aligned box of ``size`` (m) with its bottom face centred at the origin."""
    sx, sy, sz = (_positive('size', s) for s in size)
    v = np.array([[x, y, z] for x in (-sx / 2, sx / 2) for y in (-sy / 2, sy / 2)
                  for z in (0.0, sz)])
    t = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                  [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])
    return _convex_mesh(v, t)


def cylinder(radius: float = 0.01, length: float = 0.08, segments: int = 24) -> Mesh:
    """Cylinder lying along x (axis through (0, 0, radius)), touching z = 0 along a line."""
    radius = _positive('radius', radius)
    length = _positive('length', length)
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.zeros_like(a), radius * np.sin(a), radius - radius * np.cos(a)], 1)
    left = ring + [-length / 2, 0, 0]
    right = ring + [length / 2, 0, 0]
    v = np.vstack([left, right, [[-length / 2, 0, radius], [length / 2, 0, radius]]])
    n = segments
    tris = []
    for i in range(n):
        j = (i + 1) % n
        tris += [(i, n + i, n + j), (i, n + j, j), (2 * n, j, i), (2 * n + 1, n + i, n + j)]
    return _convex_mesh(v, np.array(tris))
