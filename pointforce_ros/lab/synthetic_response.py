"""A synthetic heterogeneous elastic object with known force response (tests and benchmarks).

Not physics: a closed-form stand-in for the simulated cell, used where the learner needs ground
truth it can compute instantly. A dome-shaped patch (positions in ``base``) with

- a smooth stiffness field plus a stiff circular inclusion,
- a camera-bias field: contact starts at ``d0(p, n)`` a few millimetres either side of zero. It
  is what an extrinsic calibration error does (the camera's surface is shifted by
  ``dt + dw x (p - camera)``, so the onset along the normal moves by that shift dotted with
  ``n``) plus a small smooth residual (depth-sensor bias),
- force ``f = k(p) * s ** exponent * (1 + (s / stiffening_depth) ** 2)`` with
  ``s = (d - d0(p))_+`` (``stiffening_depth = inf`` gives a pure power law),

and a poke simulator that streams a :class:`~pointforce_ros.types.PokeRecord` as the arm would:
hold at the stand-off, push at constant speed to the force or depth limit, hold, retract, with
F/T noise and a residual bias.
"""

from dataclasses import dataclass
from typing import List, Optional, Sequence

import numpy as np

from pointforce_ros.pokes.curves import extract_curve, PokeCurve
from pointforce_ros.types import PokeRecord, Surface


@dataclass(frozen=True)
class SyntheticObject:
    """Ground-truth object; all lengths in metres, forces in newtons.

    Attributes:
        size: (x, y) extent of the patch, centred on the origin.
        height: z of the dome's apex.
        radius: radius of curvature of the dome.
        k_mean: mean stiffness, N / m**exponent.
        k_variation: relative amplitude of the smooth stiffness field.
        inclusion_centre: (x, y) of the stiff inclusion.
        inclusion_radius: its radius (Gaussian sigma).
        inclusion_gain: stiffness multiplier at its centre minus one.
        camera: (3,) camera position, metres.
        camera_shift: (3,) translation error of the camera extrinsics, metres.
        camera_tilt: (3,) rotation-vector error of the camera extrinsics, radians.
        bias_amplitude: amplitude of the smooth non-rigid residual of the onset, metres.
        exponent: contact exponent (1.5 = Hertz).
        stiffening_depth: depth at which the force has doubled over the power law (inf: none).
        colour_marks_inclusion: tint the inclusion red so colour carries information.

    """

    size: tuple = (0.08, 0.06)
    height: float = 0.03
    radius: float = 0.15
    k_mean: float = 7000.0
    k_variation: float = 0.35
    inclusion_centre: tuple = (0.015, -0.01)
    inclusion_radius: float = 0.008
    inclusion_gain: float = 2.0
    camera: tuple = (0.0, 0.0, 0.45)
    camera_shift: tuple = (0.0015, -0.001, 0.0005)
    camera_tilt: tuple = (0.02, -0.015, 0.01)
    bias_amplitude: float = 0.0005
    exponent: float = 1.5
    stiffening_depth: float = np.inf
    colour_marks_inclusion: bool = True

    def surface(self, spacing: float = 0.002) -> Surface:
        """Grid samples of the dome at ``spacing`` metres, outward normals, colours."""
        nx = int(round(self.size[0] / spacing)) + 1
        ny = int(round(self.size[1] / spacing)) + 1
        x, y = np.meshgrid(np.linspace(-self.size[0] / 2, self.size[0] / 2, nx),
                           np.linspace(-self.size[1] / 2, self.size[1] / 2, ny), indexing='ij')
        x, y = x.ravel(), y.ravel()
        z = self.height - (x ** 2 + y ** 2) / (2 * self.radius)
        points = np.stack([x, y, z], axis=1)
        return Surface(points=points, normals=self.normal(points), colors=self.colour(points))

    def colour(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) RGB in [0, 1] at ``points``."""
        points = np.atleast_2d(points)
        base = np.tile([0.55, 0.45, 0.35], (len(points), 1))
        if self.colour_marks_inclusion:
            w = self._inclusion(points)[:, None]
            base = base * (1 - w) + np.array([0.8, 0.2, 0.2]) * w
        return np.clip(base, 0.0, 1.0)

    def _inclusion(self, points: np.ndarray) -> np.ndarray:
        c = np.asarray(self.inclusion_centre)
        r2 = ((points[:, :2] - c) ** 2).sum(axis=1)
        return np.exp(-0.5 * r2 / self.inclusion_radius ** 2)

    def stiffness(self, points: np.ndarray) -> np.ndarray:
        """(N,) stiffness ``k(p)``, N / m**exponent."""
        points = np.atleast_2d(points)
        x, y = points[:, 0] / self.size[0], points[:, 1] / self.size[1]
        smooth = 1 + self.k_variation * np.sin(2.2 * np.pi * x + 0.3) * np.cos(1.7 * np.pi * y)
        return self.k_mean * smooth * (1 + self.inclusion_gain * self._inclusion(points))

    def normal(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) outward unit normals of the dome at ``points`` (x, y used)."""
        points = np.atleast_2d(points)
        n = np.stack([points[:, 0] / self.radius, points[:, 1] / self.radius,
                      np.ones(len(points))], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def onset(self, points: np.ndarray) -> np.ndarray:
        """(N,) camera-bias contact onset ``d0(p, n)``, metres."""
        points = np.atleast_2d(points)
        shift = np.asarray(self.camera_shift) + np.cross(np.asarray(self.camera_tilt),
                                                         points - np.asarray(self.camera))
        rigid = (shift * self.normal(points)).sum(axis=1)
        x, y = points[:, 0] / self.size[0], points[:, 1] / self.size[1]
        return rigid + self.bias_amplitude * (0.7 * np.cos(2.0 * np.pi * x - 0.4) + 0.6 * y
                                              + 0.3 * np.sin(3.0 * np.pi * y))

    def force(self, points: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Return the true (M,) normal force in newtons at positions (M, 3) and depths (M,)."""
        points = np.atleast_2d(points)
        s = np.maximum(np.asarray(d, dtype=float) - self.onset(points), 0.0)
        stiff = 1.0 + (s / self.stiffening_depth) ** 2 if np.isfinite(self.stiffening_depth) \
            else 1.0
        return self.stiffness(points) * s ** self.exponent * stiff

    def poke(self, point, normal, rng: np.random.Generator, *, poke_id: str = 'poke-000000',
             rate: float = 250.0, speed: float = 0.002, standoff: float = 0.01,
             force_limit: float = 5.0, depth_limit: float = 0.015, hold: float = 0.2,
             ft_noise: float = 0.03, ft_bias: float = 0.05, pose_noise: float = 2e-6,
             retract_speed: Optional[float] = None) -> PokeRecord:
        """Simulate one poke and return the streamed record.

        The residual F/T bias ``ft_bias`` (N, drawn per poke in [-ft_bias, ft_bias] per axis)
        is what the tare leaves; ``ft_noise`` is the per-axis white noise sigma (N).
        """
        point = np.asarray(point, dtype=float)
        normal = np.asarray(normal, dtype=float)
        dt = 1.0 / rate
        # Push until the force limit or the depth limit (found on a fine grid, noise-free).
        d_push = np.arange(-standoff, depth_limit + 1e-12, speed * dt)
        f_push = self.force(np.repeat(point[None], len(d_push), axis=0), d_push)
        over = np.flatnonzero(f_push >= force_limit)
        end = int(over[0]) + 1 if len(over) else len(d_push)
        d_push = d_push[:end]
        n_hold = max(1, int(hold * rate))
        back = retract_speed or 2 * speed
        d_back = np.arange(d_push[-1], -standoff, -back * dt)[1:]
        d = np.concatenate([np.full(n_hold, -standoff), d_push, np.full(n_hold, d_push[-1]),
                            d_back])
        t = np.arange(len(d)) * dt
        true_f = self.force(np.repeat(point[None], len(d), axis=0), d)
        pos = point[None] - d[:, None] * normal[None] + rng.normal(0, pose_noise, (len(d), 3))
        bias = rng.uniform(-ft_bias, ft_bias, 3)
        force = true_f[:, None] * normal[None] + bias + rng.normal(0, ft_noise, (len(d), 3))
        wrench = np.hstack([force, rng.normal(0, ft_noise * 0.01, (len(d), 3))])
        pose = np.hstack([pos, np.tile([np.pi, 0.0, 0.0], (len(d), 1))])
        outcome = 'force_limit' if len(over) else 'depth_limit'
        return PokeRecord(poke_id=poke_id, point=point, normal=normal, t=t + 100.0,
                          t_controller=t + 5.0, tcp_pose=pose, wrench=wrench, speed=speed,
                          outcome=outcome, meta={'synthetic': True})

    def curves(self, surface: Surface, indices: Sequence[int], rng: np.random.Generator,
               **poke_kwargs) -> List[PokeCurve]:
        """Poke ``surface`` at ``indices`` and extract the loading curves."""
        out = []
        for k, i in enumerate(np.asarray(indices, dtype=int)):
            record = self.poke(surface.points[i], surface.normals[i], rng,
                               poke_id=f'poke-{k:06d}', **poke_kwargs)
            curve = extract_curve(record)
            meta = dict(curve.meta, surface_index=int(i))
            out.append(PokeCurve(poke_id=curve.poke_id, point=curve.point, normal=curve.normal,
                                 d=curve.d, f=curve.f, onset_d=curve.onset_d, t=curve.t,
                                 meta=meta))
        return out


def spread_indices(surface: Surface, count: int, rng: np.random.Generator,
                   margin: float = 0.004) -> np.ndarray:
    """``count`` surface indices on a jittered grid (the paper pokes on a uniform grid).

    Points within ``margin`` metres of the patch border are avoided.
    """
    p = surface.points[:, :2]
    lo, hi = p.min(axis=0) + margin, p.max(axis=0) - margin
    aspect = (hi[0] - lo[0]) / (hi[1] - lo[1])
    ny = max(1, int(round(np.sqrt(count / aspect))))
    nx = int(np.ceil(count / ny))
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], nx), np.linspace(lo[1], hi[1], ny),
                         indexing='ij')
    targets = np.stack([gx.ravel(), gy.ravel()], axis=1)[:count]
    cell = np.array([(hi[0] - lo[0]) / max(nx, 1), (hi[1] - lo[1]) / max(ny, 1)])
    targets = targets + rng.uniform(-0.25, 0.25, targets.shape) * cell
    idx = np.argmin(((p[None, :, :] - targets[:, None, :]) ** 2).sum(axis=2), axis=1)
    return np.unique(idx)
