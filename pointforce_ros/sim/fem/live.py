"""Live point-probe contact for the simulated cell (250 Hz), precomputed from nonlinear FEM.

Linear elasticity is badly wrong at poke depths (DESIGN.md section 5), so the live path carries
the nonlinear response itself: per object, full neo-Hookean pokes along the local surface normal
on a grid of surface locations give force vectors against depth. A query intersects the probe
axis with the undeformed top surface, takes the normal depth of the tip below it, and
interpolates the grid bilinearly in the surface's reference coordinates and linearly in a dense
depth table. Between grid nodes the interpolation follows a kernel-averaged stiffness of the
ground-truth field under the tip (``field_factor``), so inclusions between nodes still show
(on held-out full solves it halves the plush's error next to its firm muzzle; the grid spacing
``live.grid`` in the object YAML sets the rest). Each cache stores held-out full solves and
:func:`pointforce_ros.sim.fem.bench.bench_cell` reports the error on them.

The cache (``data/fem/live_<object>.npz``) is built by ``data/fem/make_fem_cache.py``;
it stores the source YAML's hash and is rebuilt when the object changes.
"""

from dataclasses import dataclass
import hashlib
import os
import time
from typing import Callable, Optional, Tuple

import numpy as np
from scipy.interpolate import PchipInterpolator

from pointforce_ros.sim.fem.probes import point_probe, pose_for_push
from pointforce_ros.sim.fem.solver import FemModel
from pointforce_ros.sim.objects import load_object, ObjectSpec
from pointforce_ros.errors import DataError, InvalidInput, NotConverged
from pointforce_ros.sim.fem.indentation import probe_wrench_full
from pointforce_ros.sim.fem.mesh import square_to_disk
from pointforce_ros.paths import share_path

CACHE_DIR = str(share_path('data', 'fem'))
"""Folder of the shipped live-path caches (``data/fem`` of the package's share folder)."""

LIVE_DEPTHS = np.array([0.5, 1.0, 2.0, 3.5, 5.0, 6.5, 8.0, 10.0]) * 1e-3
"""Depths (m) of the nonlinear grid pokes (cut at ``object.max_depth``)."""

POINT_PROBE = dict(tip_radius=0.002, half_angle_deg=25.0, length=0.03)
"""Geometry of the cell's tapered point probe (see :func:`probes.point_probe`)."""

CACHE_VERSION = 1

ABOVE_MARGIN = 1e-3
"""A point probe moving down whose tip is this far (metres) above the highest point of the
undeformed top (:attr:`~pointforce_ros.sim.objects.ObjectSpec.top_bound`) touches nothing:
:meth:`LiveContact.point_probe_wrench` answers zero without the surface search (the emulator
asks 500 times a second, mostly with the arm at rest above the object)."""


def spec_hash(spec: ObjectSpec) -> str:
    """Return a short hash of the object's YAML text and the cache's probe/solver settings."""
    text = open(spec.source).read() if spec.source else repr(spec)
    text += repr(POINT_PROBE) + repr(LIVE_DEPTHS.tolist()) + str(CACHE_VERSION)
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def reference_uv(spec: ObjectSpec, x, y):
    """Return reference coordinates ``(u, v)`` in [-1, 1]^2 of base-frame (x, y)."""
    u = (np.asarray(x, dtype=float) - spec.centre[0]) / (spec.size[0] / 2)
    v = (np.asarray(y, dtype=float) - spec.centre[1]) / (spec.size[1] / 2)
    if spec.kind != 'dome':
        return u, v
    # Analytic inverse of the elliptical grid mapping square -> disk.
    r2 = u * u - v * v
    s2 = 2 * np.sqrt(2.0)
    a = np.sqrt(np.maximum(2 + r2 + s2 * u, 0)) - np.sqrt(np.maximum(2 + r2 - s2 * u, 0))
    b = np.sqrt(np.maximum(2 - r2 + s2 * v, 0)) - np.sqrt(np.maximum(2 - r2 - s2 * v, 0))
    return 0.5 * a, 0.5 * b


def uv_to_xy(spec: ObjectSpec, u, v):
    """Return base-frame (x, y) of reference coordinates (inverse of :func:`reference_uv`)."""
    u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    if spec.kind == 'dome':
        u, v = square_to_disk(u, v)
    return spec.centre[0] + u * spec.size[0] / 2, spec.centre[1] + v * spec.size[1] / 2


def field_factor(spec: ObjectSpec, points: np.ndarray, normals: np.ndarray,
                 depth: float) -> np.ndarray:
    """Kernel-averaged (geometric-mean) Young's modulus under a poke, Pa.

    The kernel is a Gaussian ball centred ``0.5 depth + 2 mm`` below the surface point along
    ``-normal``, of radius ``0.5 depth + 3 mm``, sampled on a fixed stencil and clipped to the
    body. It is a smooth stand-in for how stiff the material the probe loads is; the live path
    only uses it to shape the interpolation between grid pokes.

    Args:
        points: (M, 3) surface points, metres.
        normals: (M, 3) outward unit normals.
        depth: poke depth, metres.

    Returns:
        (M,) modulus in Pa.

    """
    rng = np.random.default_rng(1234)
    stencil = rng.normal(size=(96, 3))
    centre = points - normals * (0.5 * depth + 0.002)
    radius = 0.5 * depth + 0.003
    pts = centre[:, None, :] + radius * 0.6 * stencil[None]
    pts = pts.reshape(-1, 3)
    inside = pts[:, 2] <= spec.top_height(pts[:, 0], pts[:, 1])
    inside &= (pts[:, 2] >= 0) & spec.footprint_mask(pts[:, 0], pts[:, 1])
    loge = np.log(spec.stiffness_at(pts))
    w = np.exp(-0.5 * np.sum(stencil ** 2, axis=1))
    w = np.tile(w, len(points)) * inside
    w = w.reshape(len(points), -1)
    loge = loge.reshape(len(points), -1)
    return np.exp(np.sum(w * loge, axis=1) / np.maximum(w.sum(axis=1), 1e-12))


def nonlinear_point_poke(spec: ObjectSpec, x: float, y: float, depths=None,
                         h: Optional[float] = None, force_stop: Optional[float] = None,
                         refine_at=None):
    """Full nonlinear FEM poke with the point probe along the surface normal at (x, y).

    Args:
        spec: the object.
        x, y: poke location over the footprint, metres, ``base``.
        depths: (K,) depths, metres (default :data:`LIVE_DEPTHS` up to ``spec.max_depth``).
        h: element size near the probe (default ``spec.mesh_live``).
        force_stop: with it, depths after a step that fails to converge are NaN rather than
            an error, as long as at least 3 depths were solved and the last of them pushed
            harder than this (N; the cache passes the object's force cap: the dropped depths
            lie past it, where the arm has stopped).
        refine_at: (x, y) the mesh is graded around (default the poke location).

    Returns:
        ``(depths (K,), force (K, 3) N on the probe, base; normal (3,), point (3,))``.

    Raises:
        NotConverged: the FE solve failed.

    """
    depths = _live_depths(spec) if depths is None else np.asarray(depths, dtype=float)
    h = h or spec.mesh_live
    mesh = spec.build_mesh(h, refine_at=(x, y) if refine_at is None else tuple(refine_at),
                           growth=1.5)
    model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson, support=spec.support)
    q = spec.top_point(x, y)
    n = spec.top_normal(x, y)
    # Near a stiff insert the deepest steps, far past the force cap, may not converge; the
    # caller extrapolates NaN rows, so those are dropped (checked below).
    res = model.indent(point_probe(**POINT_PROBE), pose_for_push(q, -n), -n, depths,
                       torque_centre=q, keep_solved=force_stop is not None)
    solved = len(res.depths)
    forces = np.full((len(depths), 3), np.nan)
    forces[:solved] = res.force
    if solved < len(depths) and (solved < 3 or not res.force[-1] @ n > force_stop):
        raise NotConverged(f'point poke at ({x:.4f}, {y:.4f}) m failed at '
                           f'{depths[solved] * 1e3:.1f} mm, below the force stop '
                           f'{force_stop:.1f} N')
    return depths, forces, n, q


def _live_depths(spec):
    d = LIVE_DEPTHS[LIVE_DEPTHS <= spec.max_depth + 1e-9]
    if d[-1] < spec.max_depth - 1e-9:
        d = np.append(d, spec.max_depth)
    return d


@dataclass(frozen=True)
class LiveTable:
    """Arrays of a live-path cache (see :class:`LiveContact`)."""

    u: np.ndarray          # (nx,) reference coordinates of the grid columns
    v: np.ndarray          # (ny,) reference coordinates of the grid rows
    depths: np.ndarray     # (K,) poke depths, m
    forces: np.ndarray     # (nx, ny, K, 3) force on the probe, N, base
    factor: np.ndarray     # (nx, ny, K) field_factor at the grid nodes, Pa


class LiveContact:
    """Point-probe contact answered from a precomputed nonlinear table (< 4 ms per query).

    Use :meth:`load`. Forces are the object's reaction on the probe (newtons, ``base``);
    torques are about ``torque_centre`` (N m, ``base``).
    """

    def __init__(self, spec: ObjectSpec, table: LiveTable, meta: dict):
        self.spec = spec
        self.table = table
        self.meta = dict(meta)
        self.probe_mesh = point_probe(**POINT_PROBE)
        fine = np.linspace(0.0, table.depths[-1], 201)
        self._fine_depths = fine
        self._du = fine[1] - fine[0]
        nx, ny, k, _ = table.forces.shape
        curves = np.concatenate([np.zeros((nx, ny, 1, 3)), table.forces], axis=2)
        knots = np.concatenate([[0.0], table.depths])
        fac = np.concatenate([table.factor[:, :, :1], table.factor], axis=2)
        ratio = curves / fac[..., None]
        self._ratio = PchipInterpolator(knots, ratio, axis=2)(fine)  # (nx, ny, F, 3)
        slope = (ratio[:, :, -1] - ratio[:, :, -2]) / (knots[-1] - knots[-2])
        self._slope = slope
        self._fac_depths = knots
        # field factor on a denser (u, v) lattice for the query-time correction
        nu_, nv_ = 4 * (nx - 1) + 1, 4 * (ny - 1) + 1
        self._fu = np.linspace(table.u[0], table.u[-1], nu_)
        self._fv = np.linspace(table.v[0], table.v[-1], nv_)
        self._ffac = self._factor_lattice(self._fu, self._fv, knots)

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def load(cls, object_name: str, cache_dir: Optional[str] = None,
             build: bool = True, progress: Optional[Callable[[str], None]] = None
             ) -> 'LiveContact':
        """Load the cache of ``object_name`` (name or YAML path), building it if missing.

        Raises:
            DataError: the cache is missing or stale and ``build`` is False.

        """
        spec = load_object(object_name)
        path = cache_path(spec.name, cache_dir)
        if os.path.isfile(path):
            data = np.load(path, allow_pickle=False)
            if str(data['hash']) == spec_hash(spec):
                # the field factor is derived from the YAML, so it is recomputed, not trusted
                factor = _grid_factor(spec, data['u'], data['v'], data['depths'])
                table = LiveTable(u=data['u'], v=data['v'], depths=data['depths'],
                                  forces=data['forces'], factor=factor)
                meta = {k[5:]: data[k].item() for k in data.files if k.startswith('meta_')}
                return cls(spec, table, meta)
            if not build:
                raise DataError(f'live cache {path} is stale for object {spec.name}: rebuild '
                                f'with python data/fem/make_fem_cache.py --object '
                                f'{spec.name}')
        elif not build:
            raise DataError(f'no live cache for {spec.name} at {path}: build it with python '
                            f'data/fem/make_fem_cache.py --object {spec.name}')
        live = cls.build(spec, progress=progress)
        live.save(path)
        return live

    @classmethod
    def build(cls, spec: ObjectSpec, progress: Optional[Callable[[str], None]] = None,
              margin: Optional[float] = None) -> 'LiveContact':
        """Run the grid of nonlinear pokes for ``spec`` (minutes per object).

        Args:
            margin: grid inset from the footprint edge in reference units (0..1); default
                0.18 for boxes and 0.4 for domes (whose grid corners map onto the steep rim).

        Raises:
            NotConverged: a grid poke failed.

        """
        say = progress or (lambda msg: None)
        if margin is None:
            margin = 0.4 if spec.kind == 'dome' else 0.18
        nx, ny = spec.live_grid
        u = np.linspace(-1 + margin, 1 - margin, nx)
        v = np.linspace(-1 + margin, 1 - margin, ny)
        depths = _live_depths(spec)
        forces = np.zeros((nx, ny, len(depths), 3))
        t0 = time.time()
        for i in range(nx):
            for j in range(ny):
                x, y = uv_to_xy(spec, u[i], v[j])
                _, f, n, _ = nonlinear_point_poke(spec, float(x), float(y), depths,
                                                  force_stop=spec.force_cap)
                forces[i, j] = _fill_tail(depths, f)
                k = i * ny + j + 1
                say(f'{spec.name}: grid poke {k}/{nx * ny} at ({x:.4f}, {y:.4f}) m: '
                    f'{f[~np.isnan(f[:, 0])][-1] @ n:.2f} N; {time.time() - t0:.0f} s')
        factor = _grid_factor(spec, u, v, depths)
        table = LiveTable(u=u, v=v, depths=depths, forces=forces, factor=factor)
        meta = dict(build_seconds=time.time() - t0, grid_pokes=nx * ny)
        return cls(spec, table, meta)

    def save(self, path: str):
        """Write the cache atomically to ``path`` (``.npz``)."""
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = path + '.tmp.npz'
        meta = {f'meta_{k}': np.asarray(v) for k, v in self.meta.items()}
        np.savez_compressed(tmp, hash=np.asarray(spec_hash(self.spec)), u=self.table.u,
                            v=self.table.v, depths=self.table.depths,
                            forces=self.table.forces, factor=self.table.factor, **meta)
        os.replace(tmp, path)

    # -- queries -----------------------------------------------------------------------------
    def normal_force(self, x: float, y: float, depth: float) -> float:
        """Force (N) along the outward normal for a normal poke at (x, y) to ``depth`` (m)."""
        f = self._force_at(float(x), float(y), float(depth))
        return float(f @ self.spec.top_normal(x, y))

    def point_probe_wrench(self, tip_position, axis, torque_centre=None
                           ) -> Tuple[np.ndarray, np.ndarray]:
        """Wrench on the point probe whose tip is at ``tip_position`` pushing along ``axis``.

        Args:
            tip_position: (3,) probe tip, metres, ``base``.
            axis: (3,) push direction of the probe (TCP +z), ``base``; normalised here.
            torque_centre: (3,) point the torque is taken about (default: the tip).

        Returns:
            ``(force (3,), torque (3,))``: reaction of the object on the probe, N and N m,
            ``base``. Zero when the tip is above the surface, off the object, or the axis
            does not push into the surface (more than ~78 deg from the inward normal).

        The force is interpolated from normal pokes: valid for axes near the surface normal
        (the cell pokes along the normal); an oblique axis gets the normal-poke force at
        the normal depth of the tip.

        Raises:
            InvalidInput: NaN or zero-length inputs.

        """
        p = np.asarray(tip_position, dtype=float)
        a = np.asarray(axis, dtype=float)
        if p.shape != (3,) or a.shape != (3,) or not np.all(np.isfinite(p)) \
                or not np.all(np.isfinite(a)):
            raise InvalidInput('point_probe_wrench: tip_position and axis must be finite (3,)')
        na = np.sqrt(a @ a)
        if na == 0:
            raise InvalidInput('point_probe_wrench: axis must be non-zero')
        a = a / na
        zero = np.zeros(3)
        if a[2] < 0.0 and p[2] > self.spec.top_bound + ABOVE_MARGIN:
            return zero, zero.copy()    # moving down from above every point: no contact
        q = self._surface_hit(p, a)
        if q is None:
            return zero, zero.copy()
        n = self.spec.top_normal(q[0], q[1])
        depth = float((q - p) @ n)
        if depth <= 0 or a @ n > -0.2:  # above the surface, or not pushing into it
            return zero, zero.copy()
        f = self._force_at(q[0], q[1], depth)
        c = p if torque_centre is None else np.asarray(torque_centre, dtype=float)
        return f, np.cross(p - c, f)

    def probe_wrench(self, mesh, pose, torque_centre=None) -> Tuple[np.ndarray, np.ndarray]:
        """Wrench on an arbitrary rigid probe (line paddle, cylinder, ...) at ``pose``.

        Not real-time: this runs the offline full nonlinear solve (seconds to minutes), with
        the probe approaching along its +z axis; see
        :func:`pointforce_ros.sim.fem.indentation.probe_wrench_full`.

        Returns:
            ``(force (3,), torque (3,))``, N and N m, ``base``.

        """
        return probe_wrench_full(self.spec, mesh, pose, torque_centre, h=self.spec.mesh_live)

    def _surface_hit(self, p, a):
        """Point where the line ``p + t a`` meets the undeformed top surface, or None."""
        spec = self.spec
        if abs(a[2]) < 0.2:
            return None  # nearly horizontal probe: outside the live path's validity
        t = (spec.top_height(p[0], p[1]) - p[2]) / a[2]
        for _ in range(4):
            x, y = p[0] + t * a[0], p[1] + t * a[1]
            g = spec.top_height(x, y) - (p[2] + t * a[2])
            nrm = spec.top_normal(x, y)
            dz = -(nrm[0] * a[0] + nrm[1] * a[1]) / nrm[2]  # d(top)/dt
            t += g / (a[2] - dz)
        x, y = p[0] + t * a[0], p[1] + t * a[1]
        if not spec.footprint_mask(x, y):
            return None
        return np.array([x, y, float(spec.top_height(x, y))])

    def _force_at(self, x, y, depth):
        tb = self.table
        u, v = reference_uv(self.spec, x, y)
        u = float(np.clip(u, tb.u[0], tb.u[-1]))
        v = float(np.clip(v, tb.v[0], tb.v[-1]))
        i = min(max(int(np.searchsorted(tb.u, u) - 1), 0), len(tb.u) - 2)
        j = min(max(int(np.searchsorted(tb.v, v) - 1), 0), len(tb.v) - 2)
        wu = (u - tb.u[i]) / (tb.u[i + 1] - tb.u[i])
        wv = (v - tb.v[j]) / (tb.v[j + 1] - tb.v[j])
        dmax = self._fine_depths[-1]
        dd = min(depth, dmax)
        kf = min(int(dd / self._du), len(self._fine_depths) - 2)
        wd = (dd - self._fine_depths[kf]) / self._du
        block = self._ratio[i:i + 2, j:j + 2, kf:kf + 2]  # (2, 2, 2, 3)
        wuv = np.array([[(1 - wu) * (1 - wv), (1 - wu) * wv], [wu * (1 - wv), wu * wv]])
        r = np.einsum('ij,ijkc->kc', wuv, block)
        ratio = r[0] * (1 - wd) + r[1] * wd
        if depth > dmax:
            slope = np.einsum('ij,ijc->c', wuv, self._slope[i:i + 2, j:j + 2])
            ratio = ratio + slope * (depth - dmax)
        return ratio * self._factor_query(u, v, dd)

    def _factor_lattice(self, fu, fv, knots):
        uu, vv = np.meshgrid(fu, fv, indexing='ij')
        x, y = uv_to_xy(self.spec, uu.ravel(), vv.ravel())
        pts = self.spec.top_point(x, y)
        nrm = self.spec.top_normal(x, y)
        out = np.empty((len(fu), len(fv), len(knots)))
        for k, d in enumerate(knots):
            out[:, :, k] = field_factor(self.spec, pts, nrm, max(d, knots[1])).reshape(
                len(fu), len(fv))
        return out

    def _factor_query(self, u, v, depth):
        fu, fv = self._fu, self._fv
        i = min(max(int(np.searchsorted(fu, u) - 1), 0), len(fu) - 2)
        j = min(max(int(np.searchsorted(fv, v) - 1), 0), len(fv) - 2)
        wu = (u - fu[i]) / (fu[i + 1] - fu[i])
        wv = (v - fv[j]) / (fv[j + 1] - fv[j])
        k = min(max(int(np.searchsorted(self._fac_depths, depth) - 1), 0),
                len(self._fac_depths) - 2)
        wd = (depth - self._fac_depths[k]) / (self._fac_depths[k + 1] - self._fac_depths[k])
        blk = self._ffac[i:i + 2, j:j + 2, k:k + 2]
        wuv = np.array([[(1 - wu) * (1 - wv), (1 - wu) * wv], [wu * (1 - wv), wu * wv]])
        b = np.einsum('ij,ijk->k', wuv, blk)
        return b[0] * (1 - wd) + b[1] * wd


class LiveForceModel:
    """Clean (ideal-sensor) force model for the RTDE emulator: ``wrench(tcp_pose6, t)``.

    The TCP is the probe tip and the probe pushes along the TCP +z axis. Returns the
    base-oriented ``[fx, fy, fz, tx, ty, tz]`` of the object on the probe, torque about the
    TCP (N, N m).
    """

    def __init__(self, live: LiveContact):
        self.live = live

    def wrench(self, tcp_pose6, t: float = 0.0) -> np.ndarray:
        """Wrench (6,) for a UR pose ``[x, y, z, rx, ry, rz]`` (rotation vector), ``base``."""
        pose = np.asarray(tcp_pose6, dtype=float)
        rv = pose[3:]
        angle = float(np.sqrt(rv @ rv))
        if angle < 1e-12:
            axis = np.array([0.0, 0.0, 1.0])
        else:
            k = rv / angle
            z = np.array([0.0, 0.0, 1.0])
            axis = (z * np.cos(angle) + np.cross(k, z) * np.sin(angle)
                    + k * (k @ z) * (1 - np.cos(angle)))
        f, tq = self.live.point_probe_wrench(pose[:3], axis)
        return np.concatenate([f, tq])


def force_model(object: str = 'plush', cache_dir: Optional[str] = None) -> LiveForceModel:
    """Return the emulator plug-in (``pointforce_ros.sim.fem.live:force_model``)."""
    return LiveForceModel(LiveContact.load(object, cache_dir=cache_dir, build=False))


def _fill_tail(depths, f):
    """Extrapolate NaN rows (poke stopped early at the force cap) with the last slope."""
    ok = ~np.isnan(f[:, 0])
    last = int(np.flatnonzero(ok)[-1])
    if last == len(depths) - 1:
        return f
    out = f.copy()
    if last == 0:
        slope = f[0] / depths[0]
    else:
        slope = (f[last] - f[last - 1]) / (depths[last] - depths[last - 1])
    out[last + 1:] = f[last] + slope * (depths[last + 1:, None] - depths[last])
    return out


def _grid_factor(spec, u, v, depths):
    uu, vv = np.meshgrid(u, v, indexing='ij')
    x, y = uv_to_xy(spec, uu.ravel(), vv.ravel())
    pts = spec.top_point(x, y)
    nrm = spec.top_normal(x, y)
    return np.stack([field_factor(spec, pts, nrm, d).reshape(len(u), len(v))
                     for d in depths], axis=-1)


def cache_path(name: str, cache_dir: Optional[str] = None) -> str:
    """Return the path of the live cache of object ``name``."""
    return os.path.join(cache_dir or CACHE_DIR, f'live_{name}.npz')


__all__ = ['LiveContact', 'LiveForceModel', 'force_model', 'LiveTable', 'nonlinear_point_poke',
           'field_factor', 'cache_path', 'reference_uv', 'uv_to_xy', 'spec_hash',
           'NotConverged']
