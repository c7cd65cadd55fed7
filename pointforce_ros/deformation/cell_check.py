"""One camera-only force estimate against the F/T reading on the simulated cell (for the demo).

The live cell's camera renders the object's rest shape only (the emulator does not feed it the
deformed surface), so a camera-only estimate needs the deformed views from elsewhere. This
makes them the way the wing's fixtures are made (``test/data/deformation/
make_deformation_fixtures.py``), from the cell's own pieces: its object (the ground-truth FEM,
neo-Hookean, frictionless contact, used only as the truth) and its depth camera (the
scenario's bias and noise, the ring viewpoints). Two static pushes of the cell's point probe
along the inward normal, both solved on one FE mesh so that rest and deformed views share one
discretisation:

1. an identification push: (E, nu) from its force (the F/T truth) and its deformed view
   (:func:`.identify.identify_elasticity`, as the node's ``~/identify``);
2. a held-out push: the force from its deformed view alone (:func:`.force.estimate_force`, as
   the node's ``~/estimate_force``), printed against the F/T truth of that push.

Everything the estimator sees is what a real cell gives it: the rest scan, the deformed
clouds, the contact point and (for identification only) the measured force. Units SI, frame
``base``; the forces are those on the object.
"""

from dataclasses import dataclass, replace
import time
from typing import Sequence

import numpy as np

from pointforce_ros.deformation.force import estimate_force, ForceConfig
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh


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


def _boundary_mesh(hex_mesh) -> np.ndarray:
    """(2 B, 3) triangles of a hex mesh's boundary faces (all but the bottom), outward."""
    f = hex_mesh.boundary_faces
    return np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])


def _render(camera, pose, vertices, triangles, occluder=None) -> np.ndarray:
    """Visible object points (P, 3) in ``base`` of one view, with an optional occluding mesh."""
    verts, tris = vertices, triangles
    if occluder is not None:
        verts = np.concatenate([vertices, occluder.vertices])
        tris = np.concatenate([triangles, occluder.triangles + len(vertices)])
    mesh = Mesh(verts, tris)
    _, prim, _ = camera.true_depth(mesh, pose)
    frame = camera.render(mesh, pose, organised=True)
    keep = frame.valid() & (prim >= 0) & (prim < len(triangles))
    return frame.points[keep] @ pose[:3, :3].T + pose[:3, 3]


def camera_force_check_on(spec, camera, poses: Sequence[np.ndarray], depth: float = 0.005,
                          identify_offset=(-0.015, 0.010), estimate_offset=(0.012, -0.008),
                          element_size: float = 0.004, truth_h=None) -> CameraForceCheck:
    """Identify on one static push, estimate the force of another from the camera alone.

    Args:
        spec: the cell's object (:class:`pointforce_ros.sim.objects.ObjectSpec`).
        camera: the cell's depth camera (:class:`pointforce_ros.sim.camera.DepthCamera`).
        poses: the camera's ring viewpoints ((4, 4) ``base <- optical``); all of them scan
            the rest shape, the first sees the pushes.
        depth: probe travel past contact of both pushes, metres.
        identify_offset, estimate_offset: (x, y) of the pushes from the object's centre, m.
        element_size: the estimator's mesh size, metres.
        truth_h: the ground-truth FE mesh size (default the object's live mesh size), m.

    Raises:
        InvalidInput: no viewpoint, a non-positive depth, or a push the truth cannot solve.

    """
    # the cell's ground truth (used only to make the data, never by the estimator)
    from pointforce_ros.sim.fem.live import POINT_PROBE
    from pointforce_ros.sim.fem.probes import point_probe, pose_for_push
    from pointforce_ros.sim.fem.solver import FemModel
    from pointforce_ros.rotations import quaternion_to_matrix

    t0 = time.perf_counter()
    poses = list(poses)
    if not poses or not depth > 0:
        raise InvalidInput('camera_force_check: need at least one viewpoint and depth > 0')
    h = float(truth_h or spec.mesh_live)
    hex_mesh = spec.build_mesh(h, h_z=spec.size[2] / 10)
    hex_mesh = replace(hex_mesh, top_nodes=np.arange(hex_mesh.n_nodes))
    model = FemModel(hex_mesh, spec.gauss_young(hex_mesh), spec.poisson, support=spec.support)
    tris = _boundary_mesh(hex_mesh)
    probe = point_probe(**POINT_PROBE)
    rest = np.concatenate([_render(camera, p, hex_mesh.nodes, tris) for p in poses])
    pushes = []
    for off in (identify_offset, estimate_offset):
        x, y = spec.centre[0] + off[0], spec.centre[1] + off[1]
        q = np.asarray(spec.top_point(x, y), dtype=float)
        d = -np.asarray(spec.top_normal(x, y), dtype=float)
        res = model.indent(probe, pose_for_push(q, d), d, np.linspace(0.0, depth, 5)[1:],
                           torque_centre=q)
        ppose = pose_for_push(q + depth * d, d)
        rot = quaternion_to_matrix(ppose.orientation)
        occluder = Mesh(probe.vertices @ rot.T + ppose.position, probe.triangles)
        cloud = _render(camera, poses[0], res.surface[-1], tris, occluder)
        pushes.append((q, -res.force[-1], cloud))
    mesh = volume_mesh_from_surface(rest, element_size=element_size, layers=8, grading=1.5)
    offset = rest_offsets(mesh, rest)
    q, force, cloud = pushes[0]
    fit, fem = identify_elasticity(mesh, [Poke(q, force, cloud)], IdentifyConfig(),
                                   rest_offset=offset)
    q, force, cloud = pushes[1]
    est = estimate_force(fem, q, cloud, ForceConfig(), rest_offset=offset)
    return CameraForceCheck(camera_force=est.force, camera_std=est.magnitude_std,
                            ft_force=force, contact_point=q, depth=float(depth),
                            young=fit.young, poisson=fit.poisson,
                            seconds=time.perf_counter() - t0, estimate_seconds=est.seconds)


def camera_force_check(cell, depth: float = 0.005) -> CameraForceCheck:
    """Run :func:`camera_force_check_on` with a running simulated cell's object and camera.

    Args:
        cell: a :class:`pointforce_ros.bringup.cell.CellSession` with the simulated camera
            (``cell.spec.spec``, ``cell.camera.camera``, ``cell.camera.poses``).
        depth: push depth past contact, metres.

    Raises:
        InvalidInput: the cell has no simulated object or camera (a real cell: there the
            node's ``~/estimate_force`` runs on the real camera's clouds).

    """
    sim_camera = getattr(cell, 'camera', None)
    if getattr(cell, 'spec', None) is None or sim_camera is None:
        raise InvalidInput('camera_force_check: needs the simulated object and camera; on a '
                           'real cell call /deformation_force/estimate_force during a push')
    return camera_force_check_on(cell.spec.spec, sim_camera.camera, sim_camera.poses, depth)
