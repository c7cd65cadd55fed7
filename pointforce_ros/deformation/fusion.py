"""What the deformation_force node needs for its fused camera force (issue 18).

:mod:`.fused` holds the fusion itself (the probe tip's indentation, the point model's force
there, the inverse-variance mean along the FEM's direction); :mod:`.cell_check` runs it
offline on the held-out study. This module is the node's side, on the node's own types (the
identification :class:`.identify.Poke` with its probe tip, the mesh and the identification
settings the node uses):

- :func:`fusion_data`, once per identification, from the identification pushes only: their
  probe tips and F/T magnitudes per site (kept with the model, so the point model's depth
  offset, :func:`point_calibration`, can be read again for any point model version in
  milliseconds) and the FEM's own magnitude error at a site it was not identified on
  (:func:`fem_cross_site_error`: each site left out, (E, nu) identified on the others, its
  pushes estimated from their clouds and compared with their F/T; one identification per
  site). With one site there is nothing to cross-validate and the spread is
  :data:`DEFAULT_FEM_SPREAD`.
- :func:`fuse_estimate`, per estimate: the FEM estimate fused with the point model at the
  probe tip (:func:`.fused.fuse_force`), refusing a tip that is not touching the scan.

Units SI (metres, newtons), frame ``base``; forces on the object.
"""

from dataclasses import dataclass, field
import time
from typing import Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.deformation.force import estimate_force, ForceConfig, ForceEstimate
from pointforce_ros.deformation.fused import (between_site_spread, depth_calibration,
                                              DepthCalibration, fuse_force, FusedForce,
                                              indentation_depth, point_model_force)
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import TetMesh
from pointforce_ros.errors import InvalidInput, PointforceError

DEFAULT_FEM_SPREAD = 0.3
"""Relative std of the FEM's magnitude at a new site when the identification had one site
(nothing to cross-validate): the FEM's held-out magnitude error on the cell's heterogeneous
objects (30-33 % on the vest, lamb and plush; 7 % on the homogeneous foam block)."""

SITE_RADIUS = 0.002
"""Contact points closer than this (x-y-z, metres) are one site."""


def site_labels(points, radius: float = SITE_RADIUS) -> np.ndarray:
    """(n,) site label of each contact point: points within ``radius`` of a site's first one.

    Args:
        points: (n, 3) contact points, metres.
        radius: site radius, metres.

    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    labels = np.full(len(pts), -1, dtype=int)
    first = []
    for i, p in enumerate(pts):
        for k, q in enumerate(first):
            if np.linalg.norm(p - q) <= radius:
                labels[i] = k
                break
        else:
            labels[i] = len(first)
            first.append(p)
    return labels


@dataclass(frozen=True)
class FusionData:
    """What the fused force needs from the identification pushes (stored with the model).

    Attributes:
        fem_spread: relative standard deviation of the FEM's magnitude at a site it was not
            identified on (rms of ``log(|camera| / |F/T|)``), dimensionless.
        spread_source: ``'cross-site'`` (:func:`fem_cross_site_error`), ``'between-site'``
            (:func:`.fused.between_site_spread` of the pushes' own moduli, when a
            leave-one-site-out identification was refused) or ``'default'``
            (:data:`DEFAULT_FEM_SPREAD`: one site).
        tips: (n, 3) probe tips (the TCP) of the identification pushes at their observed
            state, metres, ``base`` (NaN rows: a push without one).
        forces: (n,) their F/T magnitudes, newtons.
        sites: (n,) their site labels (:func:`site_labels`).
        errors: (k,) the cross-site log errors (empty unless ``'cross-site'``).
        seconds: wall time spent.

    """

    fem_spread: float
    spread_source: str
    tips: np.ndarray
    forces: np.ndarray
    sites: np.ndarray
    errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0

    @property
    def site_count(self) -> int:
        """Number of identification sites."""
        return int(len(np.unique(self.sites)))


def fem_cross_site_error(mesh: TetMesh, pokes: Sequence[Poke], sites,
                         config: IdentifyConfig = IdentifyConfig(), rest_offset=None
                         ) -> Tuple[float, np.ndarray]:
    """Measure the FEM's magnitude error at a site it was not identified on (one left out).

    For each site: (E, nu) identified on the other sites' pokes
    (:func:`.identify.identify_elasticity`), the site's pokes estimated from their clouds at
    their contact points (:func:`.force.estimate_force`, as the node estimates) and compared
    with their F/T. A site whose left-out identification (the other sites alone) or estimate
    is refused is skipped: the others still say how far the FEM is off.

    Args:
        mesh: the volume mesh the node identifies on.
        pokes: identification pokes (force, cloud, contact point).
        sites: (n,) site label per poke (:func:`site_labels`).
        config: identification settings (its ``load_radius`` is the estimate's too).
        rest_offset: (N,) rest offsets of the residual's reference.

    Returns:
        ``(rms, errors (n,))``: the rms of ``log(|camera| / |F/T|)`` and the errors.

    Raises:
        InvalidInput: fewer than two sites; every left-out identification or estimate refused.

    """
    sites = np.asarray(sites).ravel()
    labels = np.unique(sites)
    if len(labels) < 2 or len(sites) != len(pokes):
        raise InvalidInput(f'fem_cross_site_error: need one label per poke and two sites or '
                           f'more; got {len(labels)} site(s) for {len(pokes)} poke(s)')
    force_config = ForceConfig(load_radius=config.load_radius, match=config.match)
    errors, refused = [], []
    for label in labels:
        try:
            _, fem = identify_elasticity(mesh, [p for p, s in zip(pokes, sites) if s != label],
                                         config, rest_offset=rest_offset)
        except PointforceError as exc:   # the other sites alone do not identify: skip it
            refused.append(f'site {label}: {exc}')
            continue
        for poke in (p for p, s in zip(pokes, sites) if s == label):
            try:
                est = estimate_force(fem, poke.contact_point, poke.cloud, force_config,
                                     rest_offset=rest_offset)
            except PointforceError as exc:
                refused.append(f'a poke of site {label}: {exc}')
                continue
            errors.append(np.log(max(float(np.linalg.norm(est.force)), 1e-12)
                                 / float(np.linalg.norm(poke.force))))
    if not errors:
        raise InvalidInput('fem_cross_site_error: no site could be left out (' +
                           '; '.join(refused) + ')')
    errors = np.asarray(errors)
    return float(np.sqrt(np.mean(errors ** 2))), errors


def fusion_data(mesh: TetMesh, pokes: Sequence[Poke], fit,
                config: IdentifyConfig = IdentifyConfig(), rest_offset=None,
                cross: bool = True) -> Tuple[FusionData, str]:
    """Gather what the fused force needs, from the identification pushes only.

    Args:
        mesh, pokes, config, rest_offset: as the identification (``pokes``' tips may be None).
        fit: that identification (:class:`.identify.ElasticityFit`; its ``local_young`` is
            the fallback spread).
        cross: cross-validate the FEM's error (one identification per site); else the
            between-site spread of the pushes' own moduli.

    Returns:
        ``(FusionData, note)``: ``note`` says where the spread came from, and why when it fell
        back.

    """
    t0 = time.perf_counter()
    contacts = np.array([p.contact_point for p in pokes])
    sites = site_labels(contacts)
    tips = np.array([np.full(3, np.nan) if getattr(p, 'tip', None) is None else p.tip
                     for p in pokes]).reshape(-1, 3)
    forces = np.array([float(np.linalg.norm(p.force)) for p in pokes])
    errors = np.zeros(0)
    count = int(len(np.unique(sites)))
    if count < 2:
        spread, source = DEFAULT_FEM_SPREAD, 'default'
        note = f'FEM spread {spread:.2f} (default: one identification site)'
    else:
        spread, source, note = float('nan'), '', ''
        if cross:
            try:
                spread, errors = fem_cross_site_error(mesh, pokes, sites, config, rest_offset)
                source = 'cross-site'
                note = f'FEM spread {spread:.2f} cross-validated over {count} sites'
            except PointforceError as exc:
                note = f'no cross-site FEM error ({exc}); '
        if not source:
            local = getattr(fit, 'local_young', ())
            try:
                spread = (between_site_spread(contacts, local) if len(local) == len(pokes)
                          else float('nan'))
            except PointforceError as exc:   # a poke whose own modulus is not positive
                spread, note = float('nan'), note + f'no sites\' moduli ({exc}); '
            if np.isfinite(spread):
                source = 'between-site'
                note += f'FEM spread {spread:.2f} from the sites\' moduli'
            else:
                spread, source = DEFAULT_FEM_SPREAD, 'default'
                note += f'FEM spread {spread:.2f} (default)'
    return FusionData(fem_spread=float(spread), spread_source=source, tips=tips,
                      forces=forces, sites=sites, errors=np.asarray(errors, dtype=float),
                      seconds=time.perf_counter() - t0), note


def point_calibration(point_model, data: FusionData, radius: float = 0.005) -> DepthCalibration:
    """Read the point model's depth offset at the identification pushes (their F/T).

    Args:
        point_model: the learner's model (``surface`` with points and normals, ``response``
            a baked table).
        data: :func:`fusion_data` of the identification.
        radius: lateral radius of the depths' plane fits, metres.

    Raises:
        InvalidInput: fewer than two sites with a probe tip; as
            :func:`.fused.indentation_depth` and :func:`.fused.depth_calibration`.

    """
    use = np.all(np.isfinite(data.tips), axis=1) & (data.forces > 0)
    if len(np.unique(data.sites[use])) < 2:
        raise InvalidInput('point calibration: need identification pushes with a probe tip '
                           'at two sites or more')
    surface = point_model.surface
    depths = [indentation_depth(surface.points, surface.normals, tip, radius=radius)
              for tip in data.tips[use]]
    return depth_calibration(point_model.response, depths, data.forces[use], data.sites[use])


def fused_covariance(estimate: ForceEstimate, fused: FusedForce) -> np.ndarray:
    """Return the (3, 3) covariance of the fused force, N^2.

    The FEM's across its direction (scaled with the magnitude), the fused magnitude's variance
    along it.
    """
    d = fused.force / max(float(np.linalg.norm(fused.force)), 1e-300)
    scale = float(np.linalg.norm(fused.force)) / max(fused.fem_magnitude, 1e-300)
    across = np.eye(3) - np.outer(d, d)
    return scale ** 2 * across @ np.asarray(estimate.covariance) @ across \
        + fused.std ** 2 * np.outer(d, d)


def fuse_estimate(estimate: ForceEstimate, tip, point_model, fem_spread: float,
                  calibration: Optional[DepthCalibration] = None, radius: float = 0.005,
                  max_above: float = 0.005) -> FusedForce:
    """Fuse the FEM's camera estimate with the point model at the probe tip's depth.

    The FEM's magnitude std is its fit's combined with ``fem_spread`` of its magnitude; the
    point model's force is read at the tip's depth below the point model's scan (plus the
    calibration's offset) and the two magnitudes are averaged by inverse variance along the
    FEM's direction (:func:`.fused.fuse_force`).

    Args:
        estimate: the FEM estimate (:func:`.force.estimate_force`).
        tip: (3,) the probe tip (the arm's TCP), metres, ``base``.
        point_model: the learner's model, baked on a scan of this object.
        fem_spread: :attr:`FusionData.fem_spread` (NaN: the fit's std alone).
        calibration: :func:`point_calibration`, or None.
        radius: lateral radius of the depth's plane fit, metres.
        max_above: a tip more than this above the scanned surface is not touching it, m.

    Raises:
        InvalidInput: a non-finite tip, a tip off the scan or above it; as
            :func:`.fused.point_model_force` and :func:`.fused.fuse_force`.

    """
    tip = np.asarray(tip, dtype=float)
    if tip.shape != (3,) or not np.all(np.isfinite(tip)):
        raise InvalidInput(f'tip: need a finite (3,) probe position, m; got {tip.tolist()}')
    surface = point_model.surface
    depth = indentation_depth(surface.points, surface.normals, tip, radius=radius)
    if depth.depth < -max_above:
        raise InvalidInput(f'tip: {-depth.depth * 1e3:.1f} mm above the scanned surface (more '
                           f'than {max_above * 1e3:.1f} mm): the probe is not touching it')
    if calibration is not None:
        depth = calibration.apply(depth)
    point = point_model_force(point_model.response, depth)
    magnitude = float(np.linalg.norm(estimate.force))
    spread = float(fem_spread) if np.isfinite(fem_spread) else 0.0
    fem_std = float(np.hypot(estimate.magnitude_std, magnitude * spread))
    return fuse_force(estimate.force, fem_std, point.magnitude, point.std)
