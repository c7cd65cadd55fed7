"""Scenes with known geometry and analytic responses: tests, benchmarks and demos.

Everything here is exact by construction (flat grids, sphere caps, analytic force laws), so a
simulator result can be checked against a closed form.
"""

from typing import Optional, Union

import numpy as np
from scipy.spatial import ConvexHull

from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Mesh, Surface
from pointforce_ros.model.files import ContactModel

DEFAULT_DEPTHS = np.linspace(-0.002, 0.03, 65)
"""Displacement grid of the analytic baked responses, metres (0.5 mm steps)."""


def grid_surface(half: float = 0.05, step: float = 0.001, z: float = 0.0,
                 offset=(0.0, 0.0)) -> Surface:
    """Flat square surface ``|x|, |y| <= half`` at height ``z``, normals +z, ``base``.

    Points lie on a regular grid of ``step`` metres shifted by ``offset`` (2,) metres.
    """
    if not (step > 0 and half > 0):
        raise InvalidInput('grid_surface: half and step must be positive lengths in metres')
    ticks = np.arange(-half, half + 0.5 * step, step)
    x, y = np.meshgrid(ticks + offset[0], ticks + offset[1], indexing='ij')
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, float(z))])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return Surface(points=pts, normals=normals)


def dome_surface(n: int = 201, half: float = 0.1, radius: float = 0.3) -> Surface:
    """Sphere cap of ``radius`` whose top is the origin, sampled on an ``n`` x ``n`` xy-grid.

    ``n = 201`` over ``half = 0.1`` gives 40 401 points 1 mm apart (the benchmark surface).
    Normals point radially outward (up at the top).
    """
    if n < 2 or not (0 < half < radius / np.sqrt(2.0)):
        raise InvalidInput('dome_surface: need n >= 2 and 0 < half < radius / sqrt(2)')
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n), indexing='ij')
    x, y = x.ravel(), y.ravel()
    z = np.sqrt(radius ** 2 - x * x - y * y) - radius
    pts = np.column_stack([x, y, z])
    normals = pts - [0.0, 0.0, -radius]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Surface(points=pts, normals=normals)


def linear_response(stiffness: Union[float, np.ndarray], n_points: Optional[int] = None,
                    depths: np.ndarray = DEFAULT_DEPTHS) -> BakedResponse:
    """Baked ``y(x_i, d) = k_i max(d, 0)``: stiffness ``k`` N/m per point (or one for all)."""
    k = np.asarray(stiffness, dtype=np.float64)
    if k.ndim == 0:
        if n_points is None:
            raise InvalidInput('linear_response: give n_points with a scalar stiffness')
        k = np.full(int(n_points), float(k))
    return BakedResponse(depths=depths, forces=np.outer(k, np.clip(depths, 0.0, None)),
                         slopes=k, meta={'law': 'linear'})


def power_response(stiffness: Union[float, np.ndarray], exponent: float,
                   n_points: Optional[int] = None,
                   depths: np.ndarray = np.linspace(-0.002, 0.03, 641)) -> BakedResponse:
    """Baked ``y(x_i, d) = k_i max(d, 0) ** exponent`` (N), a non-linear law for tests."""
    k = np.asarray(stiffness, dtype=np.float64)
    if k.ndim == 0:
        if n_points is None:
            raise InvalidInput('power_response: give n_points with a scalar stiffness')
        k = np.full(int(n_points), float(k))
    top = depths[-1]
    slope = k * exponent * top ** (exponent - 1.0)
    return BakedResponse(depths=depths,
                         forces=np.outer(k, np.clip(depths, 0.0, None) ** exponent),
                         slopes=slope, meta={'law': f'power {exponent}'})


def fibonacci_sphere_mesh(n: int = 150, radius: float = 0.02) -> Mesh:
    """Return a closed sphere mesh with exactly ``n`` vertices on a Fibonacci spiral, at 0.

    Sampled at a spacing longer than its edges (e.g. 0.01 m for ``n = 150``, ``radius =
    0.02``) it gives exactly its ``n`` vertices: the paper's 150-point, 40 mm sphere.
    """
    if n < 4 or not radius > 0:
        raise InvalidInput('fibonacci_sphere_mesh: need n >= 4 and a positive radius')
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    theta = np.pi * (1.0 + 5 ** 0.5) * i
    v = radius * np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi),
                                  np.cos(phi)])
    tri = ConvexHull(v).simplices.copy()
    normal = np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]])
    inward = np.einsum('ij,ij->i', normal, v[tri].mean(axis=1)) < 0
    tri[inward] = tri[inward][:, ::-1]
    return Mesh(vertices=v, triangles=tri)


def patch_contact_model(spacing: float = 0.002, version: int = 1):
    """Return a ready-to-serve contact model: a 60 x 60 mm patch at z = 0.04 m around (0.5, 0).

    ``y = k(r) max(d, 0)^1.5`` with ``k`` doubling over a 12 mm disc at the centre (a stiff
    inclusion), shape constant 4 mm. Closed form, no learning: for node tests and benchmarks.
    """
    surface = grid_surface(half=0.03, step=spacing, z=0.04, offset=(0.5, 0.0))
    r = np.hypot(surface.points[:, 0] - 0.5, surface.points[:, 1])
    k = 4.0e3 * (1.0 + 1.0 / (1.0 + np.exp((r - 0.012) / 0.002)))  # N / m^1.5
    baked = power_response(k, 1.5, depths=np.linspace(0.0, 0.02, 41))
    baked = BakedResponse(depths=baked.depths, forces=baked.forces, slopes=baked.slopes,
                          version=version, meta={'kind': 'analytic', 'law': 'k d^1.5'})
    return ContactModel(surface=surface, response=baked, shape_constant=0.004, version=version,
                        meta={'source': 'patch_contact_model'})
