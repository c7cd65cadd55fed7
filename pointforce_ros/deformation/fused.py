"""A fused camera force: the point model's magnitude, the FEM's direction (issue 18).

On a heterogeneous object a buried stiff part (a bone, an insert panel) shields the far field
the camera sees without changing the force at the contact: the FEM, which reads the force from
the far field's deformation with an identified modulus, gets the magnitude wrong by up to 2x
there while its direction stays good. The learner's point model ``f = y(x, d)`` (fitted on
*other* pokes' F/T) gives the normal force at the contact from the indentation depth alone,
which a cell measures without the F/T: the probe tip's position (the arm's TCP) against the
scanned rest surface. This module combines the two:

- :func:`indentation_depth`: the tip's depth below the scanned surface along its normal (a
  plane fitted to the scan about the probe's line, so one noisy scan point does not set it),
  with its standard error; the depth is measured from the scan as the learner's ``d`` is
  (from the commanded point on the same scan), so the camera's bias cancels;
- :func:`point_model_force`: the point model's force and predictive standard deviation at that
  depth (the depth's own error carried through the curve's slope);
- :func:`depth_calibration`: optionally, the point model's depth offset read at the
  identification pushes (their F/T, never the held-out push's): the learner's contact onset
  (its ``d0``, from its own pokes' fits) need not sit where the scan's plane puts the surface,
  and a fraction of a millimetre there is tens of percent at 3 mm;
- :func:`between_site_spread`: how much the identification sites' own moduli disagree (the
  relative standard deviation of their log moduli): what a modulus identified on some sites
  may be off by at another, added to the FEM estimate's spread;
- :func:`fuse_force`: the inverse-variance mean of the two magnitudes along the FEM's direction,
  its standard deviation scaled by the two estimates' disagreement when it exceeds their
  spreads (the Birge ratio, as the Particle Data Group scales the error of a weighted mean).

Units SI (metres, newtons), frame ``base``; forces on the object.
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import norm, t as student_t

from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse


@dataclass(frozen=True)
class IndentationDepth:
    """The probe tip's depth below the scanned rest surface.

    Attributes:
        index: the scanned surface point (the point model's row) nearest the tip's line.
        depth: depth of the tip below the fitted scan plane along ``-normal``, metres (the
            learner's ``d``: positive = pushed in).
        std: standard error of ``depth`` from the plane fit, metres.
        normal: (3,) unit outward normal the depth is measured along, ``base``.
        points: scan points the plane was fitted to.

    """

    index: int
    depth: float
    std: float
    normal: np.ndarray
    points: int


def indentation_depth(points, normals, tip, radius: float = 0.005,
                      max_offset: float = 0.03) -> IndentationDepth:
    """Depth of the probe tip below the scanned rest surface, without the F/T.

    The normal is the mean outward normal of the scan points within ``radius`` of the point
    nearest the tip; a plane ``along = a + g . lateral`` is fitted by least squares to the
    points within ``radius`` of the tip's line along that normal (normals within 60 deg of it,
    at most ``max_offset`` along it); ``a`` is the depth.

    Args:
        points: (N, 3) scanned rest surface (the point model's surface), metres, ``base``.
        normals: (N, 3) their unit outward normals.
        tip: (3,) the probe tip's contact point at the held state (the arm's TCP), metres.
        radius: lateral radius of the plane fit, metres.
        max_offset: largest distance along the normal of a point used, metres.

    Raises:
        InvalidInput: malformed arrays, non-positive radius, or fewer than 4 scan points
            about the tip's line.

    """
    pts = np.asarray(points, dtype=float)
    nrm = np.asarray(normals, dtype=float)
    tip = np.asarray(tip, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or nrm.shape != pts.shape or tip.shape != (3,):
        raise InvalidInput(f'indentation_depth: need points and normals (N, 3) and tip (3,); '
                           f'got {pts.shape}, {nrm.shape}, {tip.shape}')
    if not np.all(np.isfinite(tip)) or not radius > 0 or not max_offset > 0:
        raise InvalidInput(f'indentation_depth: need a finite tip and radius, max_offset > 0; '
                           f'got {tip}, {radius}, {max_offset}')
    nearest = int(np.argmin(np.linalg.norm(pts - tip, axis=1)))
    around = np.linalg.norm(pts - pts[nearest], axis=1) <= radius
    n = nrm[around].sum(axis=0)
    n /= max(float(np.linalg.norm(n)), 1e-12)
    rel = pts - tip
    along = rel @ n
    lateral = rel - np.outer(along, n)
    dist = np.linalg.norm(lateral, axis=1)
    use = (dist <= radius) & (nrm @ n > 0.5) & (np.abs(along) <= max_offset)
    k = int(use.sum())
    if k < 4:
        raise InvalidInput(f'indentation_depth: {k} scan points within {radius * 1e3:.1f} mm '
                           f'of the probe line; need >= 4 (is the tip over the scanned top?)')
    a = np.column_stack([np.ones(k), lateral[use]])
    coef, *_ = np.linalg.lstsq(a, along[use], rcond=None)
    r = along[use] - a @ coef
    cov = float(r @ r) / max(k - 3, 1) * np.linalg.pinv(a.T @ a)
    index = int(np.flatnonzero(use)[np.argmin(dist[use])])
    return IndentationDepth(index=index, depth=float(coef[0]),
                            std=float(np.sqrt(max(cov[0, 0], 0.0))), normal=n, points=k)


@dataclass(frozen=True)
class PointForce:
    """The point model's normal force at a measured indentation.

    Attributes:
        magnitude: ``y(x, d)``, newtons.
        std: its standard deviation, newtons: the model's predictive one and the depth's
            error through the curve's slope.
        model_std: the model's predictive standard deviation alone, newtons.
        slope: ``dy/dd`` at the depth, N/m.
        depth: the indentation it was read at.

    """

    magnitude: float
    std: float
    model_std: float
    slope: float
    depth: IndentationDepth


def point_model_force(response: BakedResponse, depth: IndentationDepth,
                      step: float = 2.5e-4) -> PointForce:
    """Read the point model's force at ``depth`` and its standard deviation.

    Args:
        response: the learner's baked table on the surface ``depth`` was measured on.
        depth: from :func:`indentation_depth`.
        step: half-width of the central difference for the slope, metres.

    Raises:
        InvalidInput: a table without predictive std, or an index outside it.

    """
    if response.std is None:
        raise InvalidInput('point_model_force: the point model has no predictive std (a '
                           'fusion needs one); fit it with the learner (ContactGpModel)')
    i = int(depth.index)
    if not 0 <= i < len(response):
        raise InvalidInput(f'point_model_force: index {i} outside the table ({len(response)})')
    d = float(depth.depth)
    f, lo, hi = response.force(np.full(3, i), np.array([d, d - step, d + step]))
    slope = max(float(hi - lo) / (2.0 * step), 0.0)
    model_std = float(np.interp(d, response.depths, response.std[i]))
    return PointForce(magnitude=max(float(f), 0.0),
                      std=float(np.hypot(model_std, slope * depth.std)),
                      model_std=model_std, slope=slope, depth=depth)


def _inverse_depth(response: BakedResponse, index: int, force: float) -> float:
    """Return the depth (m) at which row ``index`` of the table reaches ``force`` (N)."""
    row = np.maximum.accumulate(response.forces[index])
    if force <= row[-1]:
        k = int(np.searchsorted(row, force, side='left'))
        if k == 0:
            return float(response.depths[0])
        f0, f1 = row[k - 1], row[k]
        d0, d1 = response.depths[k - 1], response.depths[k]
        return float(d0 + (force - f0) / max(f1 - f0, 1e-300) * (d1 - d0))
    slope = float(response.slopes[index])
    if not slope > 0:
        return float('inf')
    return float(response.depths[-1] + (force - row[-1]) / slope)


@dataclass(frozen=True)
class DepthCalibration:
    """A depth offset of the point model read at pushes whose force is known.

    Attributes:
        offset: added to a measured indentation depth before the model is read, metres.
        std: how far it may be off at a new site, metres (the sites' sample standard
            deviation widened by ``sqrt(1 + 1/n)``).
        site_offsets: (n,) each site's own offset (its states averaged), metres.

    """

    offset: float
    std: float
    site_offsets: np.ndarray

    def apply(self, depth: IndentationDepth) -> IndentationDepth:
        """Return the indentation with the offset added and its std widened by :attr:`std`."""
        return replace(depth, depth=depth.depth + self.offset,
                       std=float(np.hypot(depth.std, self.std)))


def depth_calibration(response: BakedResponse, depths, forces, sites) -> DepthCalibration:
    """Read the point model's depth offset at pushes with a known force (not the held-out).

    Each push's offset is the depth at which its row of the table reaches the measured force
    minus the measured indentation; pushes at one site are averaged, the sites' mean is the
    offset.

    Args:
        response: the learner's baked table.
        depths: the pushes' :class:`IndentationDepth` (:func:`indentation_depth`).
        forces: (n,) their measured force magnitudes (F/T), newtons.
        sites: (n,) a site label per push (e.g. a rounded contact point's index).

    Raises:
        InvalidInput: lengths that differ, a non-positive force, fewer than two sites, or a
            force the table never reaches.

    """
    forces = np.asarray(forces, dtype=float).ravel()
    sites = np.asarray(sites)
    if len(depths) != len(forces) or len(sites) != len(forces) or not np.all(forces > 0):
        raise InvalidInput(f'depth_calibration: need one positive force and one site per '
                           f'depth; got {len(forces)} forces and {len(sites)} sites for '
                           f'{len(depths)} depths')
    _, site = np.unique(sites.reshape(len(forces), -1), axis=0, return_inverse=True)
    site = np.ravel(site)
    if site.max(initial=-1) < 1:
        raise InvalidInput('depth_calibration: need pushes at two sites or more (one site '
                           'says nothing of how far the offset varies)')
    offset = np.array([_inverse_depth(response, int(d.index), f) - d.depth
                       for d, f in zip(depths, forces)])
    if not np.all(np.isfinite(offset)):
        raise InvalidInput('depth_calibration: a measured force lies beyond the point model\'s '
                           'table (no slope to extrapolate with)')
    per_site = np.bincount(site, offset) / np.bincount(site)
    std = float(np.std(per_site, ddof=1) * np.sqrt(1.0 + 1.0 / len(per_site)))
    return DepthCalibration(offset=float(per_site.mean()), std=std, site_offsets=per_site)


def between_site_spread(contact_points, local_young, decimals: int = 4) -> float:
    """How far a new site's modulus may be from the sites' mean (relative, of ``log E``).

    Pokes at one contact point (``decimals`` of a metre in x-y) are one site (log-averaged);
    the sample standard deviation ``s`` over the ``n`` sites, widened for a site that is not
    among them as a prediction is, ``s sqrt(1 + 1/n)``, is returned. NaN with fewer than two
    sites: one site says nothing of how the object varies.

    Args:
        contact_points: (n, 3) identification pokes' contact points, metres.
        local_young: (n,) each poke's own modulus (:attr:`.identify.ElasticityFit.local_young`).

    Raises:
        InvalidInput: lengths that differ, or a non-positive modulus.

    """
    xy = np.round(np.asarray(contact_points, dtype=float).reshape(-1, 3)[:, :2], decimals)
    e = np.asarray(local_young, dtype=float).ravel()
    if len(e) != len(xy) or not np.all(e > 0):
        raise InvalidInput(f'between_site_spread: need one positive modulus per poke; got '
                           f'{len(e)} for {len(xy)} pokes')
    _, site = np.unique(xy, axis=0, return_inverse=True)
    site = np.ravel(site)
    if site.max(initial=-1) < 1:
        return float('nan')
    mean = np.bincount(site, np.log(e)) / np.bincount(site)
    return float(np.std(mean, ddof=1) * np.sqrt(1.0 + 1.0 / len(mean)))


def small_sample_factor(sites: int, coverage: float = 0.95) -> float:
    """Widening of a spread estimated from ``sites`` sites, to the Student-t interval.

    A new site's log modulus, predicted from ``n`` sites' sample mean and standard deviation,
    follows Student's t with ``n - 1`` degrees of freedom: its ``coverage`` interval is
    ``t / z`` times the normal one (6.5 for two sites at 95 %, 1.4 for five). Multiplying
    :func:`between_site_spread` by it gives a normal spread with the t interval's coverage.

    Raises:
        InvalidInput: fewer than two sites, or a coverage outside (0, 1).

    """
    if int(sites) < 2 or not 0.0 < coverage < 1.0:
        raise InvalidInput(f'small_sample_factor: need >= 2 sites and 0 < coverage < 1; got '
                           f'{sites}, {coverage}')
    q = 0.5 * (1.0 + float(coverage))
    return float(student_t.ppf(q, int(sites) - 1) / norm.ppf(q))


@dataclass(frozen=True)
class FusedForce:
    """The fused force estimate.

    Attributes:
        force: (3,) fused force on the object, newtons, ``base``: the FEM's direction.
        std: standard deviation of ``|force|``, newtons (Birge-scaled, see ``scale``).
        point_weight: weight of the point model's magnitude in the mean, in [0, 1].
        fem_magnitude: the FEM's ``|F|``, newtons.
        fem_std: its standard deviation, newtons.
        point_magnitude: the point model's force, newtons.
        point_std: its standard deviation, newtons.
        scale: the factor the inverse-variance std was scaled by (>= 1: the two magnitudes'
            disagreement over their combined spread when larger than 1).

    """

    force: np.ndarray
    std: float
    point_weight: float
    fem_magnitude: float
    fem_std: float
    point_magnitude: float
    point_std: float
    scale: float


def fuse_force(fem_force, fem_std: float, point_magnitude: float, point_std: float,
               birge: bool = True) -> FusedForce:
    """Inverse-variance mean of the FEM's and the point model's magnitudes, FEM direction.

    Args:
        fem_force: (3,) the FEM camera estimate, newtons, ``base``.
        fem_std: standard deviation of its magnitude, newtons (``inf``: no weight).
        point_magnitude: the point model's force at the measured indentation, newtons.
        point_std: its standard deviation, newtons (``inf``: no weight).
        birge: scale the weighted mean's standard deviation by the Birge ratio
            ``max(1, |a - b| / sqrt(sa^2 + sb^2))`` (two estimates that disagree beyond their
            spreads do not make a tighter one).

    Raises:
        InvalidInput: a zero or non-finite FEM force (no direction), a negative or NaN
            magnitude or std, or both stds infinite.

    """
    f = np.asarray(fem_force, dtype=float)
    if f.shape != (3,) or not np.all(np.isfinite(f)) or not np.linalg.norm(f) > 0:
        raise InvalidInput(f'fuse_force: the FEM force must be a finite non-zero (3,) vector '
                           f'(its direction is used); got {f}')
    a, b = float(np.linalg.norm(f)), float(point_magnitude)
    sa, sb = float(fem_std), float(point_std)
    if not (np.isfinite(b) and b >= 0 and sa >= 0 and sb >= 0):   # NaN fails every compare
        raise InvalidInput(f'fuse_force: need a finite point magnitude >= 0 and stds >= 0; '
                           f'got {b}, {sa}, {sb}')
    if np.isinf(sa) and np.isinf(sb):
        raise InvalidInput('fuse_force: both standard deviations are infinite')
    if sa == 0 and sb == 0:
        wa, wb = 0.5, 0.5
        std = 0.0
    elif sa == 0 or sb == 0:
        wa, wb = float(sa == 0), float(sb == 0)
        std = 0.0
    else:
        ia, ib = 1.0 / sa ** 2, 1.0 / sb ** 2
        wa, wb = ia / (ia + ib), ib / (ia + ib)
        std = float(np.sqrt(1.0 / (ia + ib)))
    combined = float(np.hypot(sa, sb))
    scale = 1.0
    if birge and np.isfinite(combined) and combined > 0:
        scale = max(1.0, abs(a - b) / combined)
    magnitude = wa * a + wb * b
    return FusedForce(force=f / a * magnitude, std=std * scale, point_weight=wb,
                      fem_magnitude=a, fem_std=sa, point_magnitude=b, point_std=sb,
                      scale=scale)
