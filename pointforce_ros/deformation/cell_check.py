"""One camera-only force estimate against the F/T reading (seed 001 on the cell, for the demo).

The live cell's camera renders the object's rest shape only (the emulator does not feed it the
deformed surface), so the demo's check makes deformed views the way the wing's fixtures are
made (``test/data/deformation/make_deformation_fixtures.py``) and hands them here. The data
making needs the simulated cell (its FEM truth and camera), which the house rule keeps out of
this wing: it lives in ``bringup`` (``test/data/deformation/bringup_camera_check.py`` until it
is moved there). This module is the estimator's side:

1. (E, nu) from one push's force (the F/T truth) and its deformed views
   (:func:`.identify.identify_elasticity`, as the node's ``~/identify``);
2. the force of another, held-out push from its deformed view alone
   (:func:`.force.estimate_force`, as the node's ``~/estimate_force``), to print against the
   F/T reading of that push.

The estimator sees what a real cell gives it: the rest scan with normals, the deformed clouds,
the camera pose, the contact point from the arm (moved along the camera's line of sight onto the
scan, :func:`contact_on_scan`: a camera depth bias otherwise offsets the dent from the load
sideways) and, for identification only, the measured force. Units SI, frame ``base``; forces
on the object.
"""

from dataclasses import dataclass
import time
import numpy as np

from pointforce_ros.deformation.force import estimate_force, ForceConfig
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets


@dataclass(frozen=True)
class CameraForceCheck:
    """A camera-only force estimate against the F/T truth of the same static push.

    Attributes:
        camera_force: (3,) estimated force on the object, newtons, ``base``.
        camera_std: standard deviation of ``|camera_force|`` from the fit, newtons.
        ft_force: (3,) the F/T truth (the cell's FEM) of that push, newtons, ``base``.
        contact_point: (3,) the push's contact point, metres, ``base``.
        depth: probe travel past contact, metres.
        young: identified Young's modulus, Pa (from the other push).
        poisson: identified Poisson ratio.
        seconds: wall time in all (the two ground-truth solves dominate).
        estimate_seconds: wall time of the estimate alone.

    """

    camera_force: np.ndarray
    camera_std: float
    ft_force: np.ndarray
    contact_point: np.ndarray
    depth: float
    young: float
    poisson: float
    seconds: float
    estimate_seconds: float

    @property
    def magnitude_error(self) -> float:
        """``| |camera| - |F/T| | / |F/T|``."""
        ft = float(np.linalg.norm(self.ft_force))
        return abs(float(np.linalg.norm(self.camera_force)) - ft) / max(ft, 1e-12)

    @property
    def direction_error_deg(self) -> float:
        """Angle between the camera and F/T force vectors, degrees."""
        a, b = self.camera_force, self.ft_force
        c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-300)
        return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))

    def line(self) -> str:
        """One printable line: camera estimate, F/T reading, errors."""
        return (f'camera-only force {np.round(self.camera_force, 2).tolist()} N '
                f'(|F| {np.linalg.norm(self.camera_force):.2f} +- {self.camera_std:.2f} N) '
                f'against F/T {np.round(self.ft_force, 2).tolist()} N '
                f'(|F| {np.linalg.norm(self.ft_force):.2f} N): magnitude error '
                f'{100 * self.magnitude_error:.1f} %, direction {self.direction_error_deg:.1f} '
                f'deg; model E {self.young / 1e3:.1f} kPa, nu {self.poisson:.2f} from another '
                f'push; {self.depth * 1e3:.1f} mm push, estimate {self.estimate_seconds * 1e3:.0f}'
                f' ms, {self.seconds:.0f} s in all')


def contact_on_scan(contact, scan: np.ndarray, camera_origin, radius: float = 0.002
                    ) -> np.ndarray:
    """Move the contact point along the camera's line of sight onto the scanned surface.

    A depth bias moves every scanned point along its viewing ray; the contact point comes
    from the arm, in the true frame. Moving it along the ray through it until it meets the
    scan (the median ray distance of the scan points within ``radius`` of that ray) puts
    it where the scan saw that surface point, with only the camera pose known.

    Args:
        contact: (3,) contact point from the arm, metres, ``base``.
        scan: (P, 3) rest scan, metres, ``base``.
        camera_origin: (3,) optical centre of the camera that took the scan.
        radius: lateral radius about the ray, metres.

    Returns:
        (3,) the contact point on the scan (unchanged when no scan point is near the ray).

    """
    q = np.asarray(contact, dtype=float)
    ray = q - np.asarray(camera_origin, dtype=float)
    ray /= np.linalg.norm(ray)
    rel = np.asarray(scan, dtype=float) - q
    along = rel @ ray
    lateral = np.linalg.norm(rel - np.outer(along, ray), axis=1)
    near = (lateral <= radius) & (np.abs(along) <= 0.01)
    if not near.any():
        return q
    return q + float(np.median(along[near])) * ray


def check_from_views(rest, rest_normals, identify_states, estimate_state, camera_origin,
                     element_size: float = 0.004, depth: float = float('nan'),
                     started: float = None) -> CameraForceCheck:
    """Identify on one push's states, estimate another push's force from its view alone.

    Args:
        rest: (P, 3) rest scan, metres, ``base``.
        rest_normals: (P, 3) its outward normals (they matter: without them side points enter
            the top's height field; measured on the foam block's fixtures: E 15-17 kPa and nu
            0.49 instead of 55 kPa and 0.2-0.25).
        identify_states: ``[(contact point (3,), force on the object (3,), cloud (Q, 3))]``
            of the identification push (any depths).
        estimate_state: ``(contact point, F/T force, cloud)`` of the held-out push; its force
            is only compared with, never used.
        camera_origin: (3,) optical centre of the camera that saw the pushes.
        element_size: the estimator's mesh size, metres.
        depth: the held-out push's depth (reported), metres.
        started: ``time.perf_counter()`` when the data making began (for ``seconds``).

    Raises:
        InvalidInput: as :func:`.identify.identify_elasticity` and :func:`.force.estimate_force`.

    """
    t0 = time.perf_counter() if started is None else started
    mesh = volume_mesh_from_surface(rest, rest_normals, element_size=element_size, layers=8,
                                    grading=1.5)
    offset = rest_offsets(mesh, rest)
    pokes = [Poke(contact_on_scan(q, rest, camera_origin), f, c) for q, f, c in identify_states]
    fit, fem = identify_elasticity(mesh, pokes, IdentifyConfig(), rest_offset=offset)
    q, force, cloud = estimate_state
    est = estimate_force(fem, contact_on_scan(q, rest, camera_origin), cloud, ForceConfig(),
                         rest_offset=offset)
    return CameraForceCheck(camera_force=est.force, camera_std=est.magnitude_std,
                            ft_force=np.asarray(force, dtype=float),
                            contact_point=np.asarray(q, dtype=float), depth=float(depth),
                            young=fit.young, poisson=fit.poisson,
                            seconds=time.perf_counter() - t0, estimate_seconds=est.seconds)
