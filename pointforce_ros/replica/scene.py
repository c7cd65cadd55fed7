"""PyBullet scene of the replica: a neo-Hookean soft body on a table, poked by a prismatic pusher.

PyBullet soft bodies report no contact force, so the force is read where seed 002's
revolute-prismatic robot read it: through the pusher's joint. The pusher is a URDF with a fixed
base and one prismatic joint along the push direction; its tip link is a sphere of the probe's
tip radius. The joint is driven in position control and the force the motor applies
(``getJointState(...)[3]``) is the force the body pushes back with, once tared on the samples
before contact (as the F/T sensor is tared right before a poke). The depth is the joint's
measured position, not its target.

Engine traits found on this machine (PyBullet 3.2.7, DIRECT), handled here, not hidden:

* At the cell's own scale (a 90 mm body, a 2 mm tip) the rigid tip passes through the soft
  body's surface (nodes end up above the tip; the motor force stays at zero) whatever the mesh,
  the solver iterations, the tip mass or the control mode. Scaled up ``scale`` times (default
  10: a 0.9 m body) the same contact holds and the force is smooth and monotonic. The scene
  therefore simulates lengths times ``scale``; a quasi-static neo-Hookean force scales as
  ``mu L^2``, so the force reported in cell units is the engine's divided by ``scale^2`` (with
  the Lame parameters in pascals, unchanged). Time is not scaled (speeds are times ``scale``).
  Keeping inertia in the same
  ratio to elasticity would need the mass times ``scale``; that made the engine unstable
  (non-finite or wild motor forces, minutes per poke), so the simulated mass is the real mass
  times ``scale^3`` (the geometry scaled at constant density), which is stable; inertia then
  weighs ``scale^2`` more than in the cell, which only matters for the dynamic response.
* Gravity is off: the cell's FEM ground truth has no self weight, and a weightless pusher
  needs no tare beyond the first samples.
* A flat plate (``SceneConfig.pusher = 'plate'``, seed 002's compression of a ball) also
  passes through a 90 mm ball's top nodes at the cell's scale (0.1 N instead of ~40 N at
  30 mm on a 7.5 mm mesh) and holds at ``scale`` 10. Under it the motor alone stops ~2 mm
  short of its target (``track_gain`` corrects the target), and the motor force rings on
  the contact (~4 % step to step, +-5 % after a 0.1 s ``force_window``); the static curve is
  read through a quartic in depth (``static_degree``). The outcome is chaotic at that level:
  moving the nodes by 1e-9 m moved a 15 mm ball's error at 30 mm from 4.93 to 4.70 %.
* The response depends on mesh resolution and the contact margin (contact starts about a
  margin early); a replica records both, see :mod:`pointforce_ros.replica.traits`.

All inputs and outputs are in cell units: metres, newtons, seconds, frame ``base``.
"""

from dataclasses import dataclass
import os
from pathlib import Path
import tempfile
from typing import Optional, Tuple

import numpy as np
import pybullet as pb

from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.replica.mesh import TetMesh, write_vtk
from pointforce_ros.types import as_array, unit_rows


@dataclass(frozen=True)
class Material:
    """Soft-body material as PyBullet takes it.

    Attributes:
        mu: second Lame parameter (shear modulus), Pa.
        lam: first Lame parameter, Pa.
        damping: PyBullet ``NeoHookeanDamping`` (engine-specific, seconds-like; default 0.03
            in seed 002's runs).

    Raises:
        InvalidInput: non-positive or non-finite values.

    """

    mu: float
    lam: float
    damping: float = 0.03

    def __post_init__(self):
        for name in ('mu', 'lam'):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise InvalidInput(f'Material.{name}: must be > 0 Pa, got {value}')
            object.__setattr__(self, name, value)
        damping = float(self.damping)
        if not (np.isfinite(damping) and damping >= 0):
            raise InvalidInput(f'Material.damping: must be >= 0, got {damping}')
        object.__setattr__(self, 'damping', damping)

    @classmethod
    def from_young(cls, young: float, poisson: float, damping: float = 0.03) -> 'Material':
        """Lame parameters of Young's modulus ``young`` (Pa) and Poisson ratio ``poisson``."""
        if not (0.0 < poisson < 0.5):
            raise InvalidInput(f'Material.from_young: Poisson ratio must lie in (0, 0.5), '
                               f'got {poisson}')
        mu = young / (2.0 * (1.0 + poisson))
        lam = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
        return cls(mu=mu, lam=lam, damping=damping)

    @property
    def poisson(self) -> float:
        """Poisson ratio ``lam / (2 (lam + mu))``."""
        return self.lam / (2.0 * (self.lam + self.mu))

    @property
    def young(self) -> float:
        """Young's modulus ``mu (3 lam + 2 mu) / (lam + mu)``, Pa."""
        return self.mu * (3 * self.lam + 2 * self.mu) / (self.lam + self.mu)

    def scaled(self, k: float) -> 'Material':
        """Both Lame parameters times ``k``, same damping."""
        return Material(self.mu * k, self.lam * k, self.damping)


PUSHERS = ('probe', 'plate')
"""Pushers a scene can carry: the cell's point probe, or seed 002's flat plate."""


@dataclass(frozen=True)
class SceneConfig:
    """Fixed engine settings of a replica (recorded with it).

    Attributes:
        scale: engine length units per metre (see the module note), dimensionless.
        time_step: seconds per engine step.
        solver_iterations: ``numSolverIterations`` of the engine.
        probe_radius: tip sphere radius, metres (the cell's point probe: 2 mm).
        probe_half_angle: half-angle of the probe's cone behind the tip, degrees (the cell's
            point probe: 25); 0 makes the probe a bare sphere.
        collision_margin: soft-body collision margin, metres (contact starts this early).
        friction: soft-body friction coefficient.
        density: body density, kg/m^3 (sets the nodal masses).
        tip_mass: mass of the pusher's moving link, kg (engine units).
        position_gain, velocity_gain: PyBullet position-control gains of the pusher.
        max_force: motor force limit, engine newtons.
        face_contact: PyBullet ``useFaceContact``.
        pusher: ``'probe'`` (the cell's point probe, :func:`probe_obj`) or ``'plate'`` (a
            flat square plate: seed 002's compression of a ball, distributed contact).
        plate_half_width: half the plate's side, metres (``'plate'`` only).
        track_gain: integral correction of the joint target, per step, as a fraction of the
            tracking error (the measured position then follows the path; with 0 the motor
            alone stops ~2 mm short under a plate's load).
        force_window: centred moving average of the motor force, seconds (0: raw), as an F/T
            sensor's low-pass: under a plate the raw motor force jitters by ~4 % step to step.
        static_degree: degree of the polynomial in depth the static loading curve is read
            through (least squares over the loaded samples; 0: the samples themselves). Under
            a plate the body rings on the contact (~15 Hz, +-5 % even after ``force_window``).
        onset: where a simulated depth counts from: ``'force'`` (where the force first
            exceeds 1 % of its peak, as a fitted onset of measured pokes) or ``'geometry'``
            (the undeformed top, less the collision margin: truth counted from contact).
        anchor_height: the body's nodes within this height of its lowest node are anchored
            to the table, metres (0: the lowest nodes only). A ball touches the table at one
            node; anchored there alone it tilts under a frictionless plate (rotating about
            the pin lowers its top), which neither the cell's ball nor its FEM truth does.

    """

    scale: float = 10.0
    time_step: float = 0.004
    solver_iterations: int = 50
    probe_radius: float = 0.002
    probe_half_angle: float = 25.0
    collision_margin: float = 0.0005
    friction: float = 0.5
    density: float = 1000.0
    tip_mass: float = 10.0
    position_gain: float = 0.2
    velocity_gain: float = 1.0
    max_force: float = 1.0e4
    face_contact: bool = True
    pusher: str = 'probe'
    plate_half_width: float = 0.075
    track_gain: float = 0.0
    force_window: float = 0.0
    static_degree: int = 0
    onset: str = 'force'
    anchor_height: float = 0.0

    def __post_init__(self):
        for name in ('scale', 'time_step', 'probe_radius', 'density', 'tip_mass', 'max_force'):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0):
                raise InvalidInput(f'SceneConfig.{name}: must be > 0, got {value}')
        if int(self.solver_iterations) < 1:
            raise InvalidInput('SceneConfig.solver_iterations: must be >= 1')
        if self.pusher not in PUSHERS:
            raise InvalidInput(f'SceneConfig.pusher: {self.pusher!r} is not one of {PUSHERS}')
        if self.onset not in ('force', 'geometry'):
            raise InvalidInput(f"SceneConfig.onset: {self.onset!r} is not 'force' or 'geometry'")
        if not (np.isfinite(self.plate_half_width) and self.plate_half_width > 0):
            raise InvalidInput('SceneConfig.plate_half_width: must be > 0')
        if not (np.isfinite(self.anchor_height) and self.anchor_height >= 0):
            raise InvalidInput('SceneConfig.anchor_height: must be >= 0 m')


def probe_obj(radius: float, half_angle_deg: float, length: float, segments: int = 24) -> str:
    """Wavefront OBJ text of the tapered point probe (convex): spherical tip, cone behind it.

    The tip's leading point is the origin, the push direction +z, the cone opens towards -z
    (the cell's :func:`pointforce_ros.sim.fem.probes.point_probe` geometry). Engine units.
    """
    alpha = np.radians(half_angle_deg)
    ang = np.linspace(0.0, np.pi / 2 - alpha, 8)[1:]
    ring_r = radius * np.sin(ang)
    ring_z = -(radius - radius * np.cos(ang))
    r_top = ring_r[-1] + (length + ring_z[-1]) * np.tan(alpha)
    ring_r = np.append(ring_r, r_top)
    ring_z = np.append(ring_z, -length)
    theta = 2 * np.pi * np.arange(segments) / segments
    verts = [(0.0, 0.0, 0.0)]
    for r, z in zip(ring_r, ring_z):
        verts += [(r * np.cos(t), r * np.sin(t), z) for t in theta]
    verts.append((0.0, 0.0, -length))
    lines = [f'v {x:.9g} {y:.9g} {z:.9g}' for x, y, z in verts]
    ring = [1 + 1 + k * segments + np.arange(segments) for k in range(len(ring_r))]
    for j in range(segments):
        lines.append(f'f 1 {ring[0][j]} {ring[0][(j + 1) % segments]}')
    for a, b in zip(ring[:-1], ring[1:]):
        for j in range(segments):
            k = (j + 1) % segments
            lines.append(f'f {a[j]} {b[j]} {b[k]}')
            lines.append(f'f {a[j]} {b[k]} {a[k]}')
    for j in range(segments):
        lines.append(f'f {len(verts)} {ring[-1][(j + 1) % segments]} {ring[-1][j]}')
    return '\n'.join(lines) + '\n'


def pusher_urdf(probe_radius: float, tip_mass: float, travel: float,
                mesh_file: Optional[str] = None, plate_half_width: float = 0.0) -> str:
    """URDF text of the pusher: fixed ``base``, prismatic ``push`` joint along +z, probe tip.

    Lengths in engine units. The joint's +z is the push direction once the base is oriented.
    The tip's collision is a square plate of half side ``plate_half_width`` (when > 0; its
    pressing face at the link origin, ``probe_radius`` thick behind it), else ``mesh_file``
    (a :func:`probe_obj`, leading point at the link origin) or, without one, a sphere whose
    leading point is at the link origin.
    """
    if plate_half_width > 0:
        w, t = plate_half_width, probe_radius
        geometry = (f'<origin xyz="0 0 {-t:.9g}"/>'
                    f'<geometry><box size="{2 * w:.9g} {2 * w:.9g} {2 * t:.9g}"/></geometry>')
    elif mesh_file:
        geometry = f'<origin xyz="0 0 0"/><geometry><mesh filename="{mesh_file}"/></geometry>'
    else:
        geometry = (f'<origin xyz="0 0 {-probe_radius:.9g}"/>'
                    f'<geometry><sphere radius="{probe_radius:.9g}"/></geometry>')
    inertia = 0.4 * tip_mass * probe_radius ** 2
    return f'''<?xml version="1.0"?>
<robot name="pusher">
  <link name="base">
    <inertial><mass value="0"/>
      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
  </link>
  <link name="tip">
    <inertial><mass value="{tip_mass:.9g}"/>
      <inertia ixx="{inertia:.9g}" ixy="0" ixz="0" iyy="{inertia:.9g}" iyz="0"
               izz="{inertia:.9g}"/></inertial>
    <collision>{geometry}</collision>
  </link>
  <joint name="push" type="prismatic">
    <parent link="base"/><child link="tip"/><axis xyz="0 0 1"/>
    <limit lower="{-travel:.9g}" upper="{travel:.9g}" effort="1e9" velocity="100"/>
  </joint>
</robot>
'''


def _quat_z_to(direction: np.ndarray) -> Tuple[float, float, float, float]:
    """Quaternion (x, y, z, w) rotating +z onto unit ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.clip(z @ direction, -1.0, 1.0))
    axis = np.cross(z, direction)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return (0.0, 0.0, 0.0, 1.0) if c > 0 else (1.0, 0.0, 0.0, 0.0)
    axis = axis / s
    half = 0.5 * np.arccos(c)
    return tuple(np.append(axis * np.sin(half), np.cos(half)))


@dataclass(frozen=True)
class PokeTrace:
    """A simulated poke, in cell units.

    Attributes:
        t: (T,) seconds since the start of the poke.
        depth: (T,) measured tip displacement past the undeformed top along ``-normal``,
            metres (the joint's position, not its target).
        force: (T,) force of the body on the tip along ``normal``, newtons, tared on the
            samples before contact.
        target: (T,) commanded depth, metres.

    """

    t: np.ndarray
    depth: np.ndarray
    force: np.ndarray
    target: np.ndarray


class ReplicaScene:
    """One PyBullet DIRECT client holding the table, the soft body and one pusher.

    Use as a context manager, or call :meth:`close`. Every method works in cell units.

    Raises:
        InvalidInput: bad mesh or configuration.

    """

    def __init__(self, mesh: TetMesh, material: Material,
                 config: SceneConfig = SceneConfig(), vtk_path: Optional[str] = None):
        """Build the scene; writes the scaled VTK to a temporary file unless given one."""
        self.mesh = mesh
        self.material = material
        self.config = config
        self._tmp = None
        self.client = pb.connect(pb.DIRECT)
        try:
            self._build(vtk_path)
        except Exception:
            pb.disconnect(self.client)
            raise

    def _build(self, vtk_path):
        cfg, s, c = self.config, self.config.scale, self.client
        pb.resetSimulation(pb.RESET_USE_DEFORMABLE_WORLD, physicsClientId=c)
        pb.setGravity(0, 0, 0, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=cfg.time_step,
                                     numSolverIterations=int(cfg.solver_iterations),
                                     physicsClientId=c)
        lo = self.mesh.nodes.min(axis=0)
        hi = self.mesh.nodes.max(axis=0)
        centre = 0.5 * (lo + hi) * s
        half = np.append(0.5 * (hi - lo)[:2] * s + 0.5 * s, 0.01 * s)
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half.tolist(),
                                        physicsClientId=c)
        table_at = [centre[0], centre[1], -half[2]]
        self.table_id = pb.createMultiBody(0, shape, basePosition=table_at, physicsClientId=c)
        if vtk_path is None:
            self._tmp = tempfile.TemporaryDirectory(prefix='replica-')
            vtk_path = os.path.join(self._tmp.name, 'body.vtk')
            write_vtk(self.mesh, vtk_path)
        self.vtk_path = str(vtk_path)
        mass = cfg.density * self.mesh.volume * s ** 3
        m = self.material
        self.body_id = pb.loadSoftBody(
            self.vtk_path, basePosition=[0, 0, 0], scale=s, mass=mass, useNeoHookean=1,
            NeoHookeanMu=m.mu, NeoHookeanLambda=m.lam, NeoHookeanDamping=m.damping,
            useSelfCollision=0, frictionCoeff=cfg.friction,
            collisionMargin=cfg.collision_margin * s, useFaceContact=int(cfg.face_contact),
            physicsClientId=c)
        if self.body_id < 0:
            raise InvalidInput(f'PyBullet could not load the soft body {self.vtk_path}')
        for node in self.mesh.bottom_nodes(max(1e-6, cfg.anchor_height)):
            pb.createSoftBodyAnchor(self.body_id, int(node), -1, -1, physicsClientId=c)
        self.pusher_id = None

    # -- pusher ------------------------------------------------------------------------------
    def place_pusher(self, start, direction, travel: float = 0.1) -> int:
        """Load the pusher with its tip's leading point at ``start`` pushing along ``direction``.

        Args:
            start: (3,) metres, ``base``: the tip's leading point at joint position 0.
            direction: (3,) unit push direction, ``base``.
            travel: joint range either way, metres.

        Returns:
            The pusher's body id (a previous pusher is removed).

        """
        start = as_array(start, 'start', (3,))
        direction = unit_rows(as_array(direction, 'direction', (3,)), 'direction')
        cfg, s, c = self.config, self.config.scale, self.client
        if self.pusher_id is not None:
            pb.removeBody(self.pusher_id, physicsClientId=c)
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix='replica-')
        path = Path(self._tmp.name) / 'pusher.urdf'
        mesh_file = None
        plate = cfg.plate_half_width * s if cfg.pusher == 'plate' else 0.0
        if cfg.probe_half_angle > 0 and not plate:
            mesh_file = str(Path(self._tmp.name) / 'probe.obj')
            Path(mesh_file).write_text(probe_obj(cfg.probe_radius * s, cfg.probe_half_angle,
                                                 0.03 * s))
        path.write_text(pusher_urdf(cfg.probe_radius * s, cfg.tip_mass, travel * s,
                                    mesh_file, plate))
        base = start * s
        self.pusher_id = pb.loadURDF(str(path), basePosition=base.tolist(),
                                     baseOrientation=_quat_z_to(direction), useFixedBase=True,
                                     physicsClientId=c)
        pb.setJointMotorControl2(self.pusher_id, 0, pb.VELOCITY_CONTROL, force=0,
                                 physicsClientId=c)
        self._direction = direction
        return self.pusher_id

    def joint_force(self) -> Tuple[float, float]:
        """Return the joint position (metres) and the motor force along the push (newtons).

        Both in cell units: position / scale, force / scale^2.
        """
        s = self.config.scale
        state = pb.getJointState(self.pusher_id, 0, physicsClientId=self.client)
        return state[0] / s, state[3] / s ** 2

    def drive(self, target_path: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Step once per entry of ``target_path`` (joint targets, metres).

        Returns:
            ``(position, force)``, each (T,), cell units.

        Raises:
            NotConverged: the engine returned a non-finite state (the body blew up).

        """
        cfg, s, c = self.config, self.config.scale, self.client
        pos = np.empty(len(target_path))
        force = np.empty(len(target_path))
        offset = 0.0
        for k, target in enumerate(target_path):
            pb.setJointMotorControl2(self.pusher_id, 0, pb.POSITION_CONTROL,
                                     targetPosition=(float(target) + offset) * s,
                                     force=cfg.max_force,
                                     positionGain=cfg.position_gain,
                                     velocityGain=cfg.velocity_gain, physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
            pos[k], force[k] = self.joint_force()
            offset += cfg.track_gain * (float(target) - pos[k])
            if not (np.isfinite(pos[k]) and np.isfinite(force[k])):
                raise NotConverged(f'PyBullet state became non-finite at step {k} '
                                   f'(material mu={self.material.mu:.4g} Pa, '
                                   f'lambda={self.material.lam:.4g} Pa, mesh '
                                   f'{self.mesh.resolution * 1e3:.3g} mm): the body is '
                                   'unstable at these settings')
        return pos, force

    def top_height(self, xy) -> float:
        """Undeformed top height (metres) of the body's mesh under ``xy`` (2,), nearest nodes."""
        xy = as_array(xy, 'xy', (2,))
        nodes = self.mesh.nodes
        dist = np.linalg.norm(nodes[:, :2] - xy, axis=1)
        near = dist <= dist.min() + 0.75 * self.mesh.resolution
        return float(nodes[near, 2].max())

    def poke(self, xy, depths, speed: float, hold: float = 0.0, standoff: float = 0.002,
             tare_time: float = 0.05, retract: bool = True) -> PokeTrace:
        """Push vertically at ``xy`` along the schedule the cell's poke server uses.

        The tip starts ``standoff`` above the undeformed top at ``xy``, waits ``tare_time``,
        moves down at ``speed`` to ``max(depths)`` (metres past the top), holds ``hold``
        seconds, and retracts at ``speed`` to the start.

        Args:
            xy: (2,) metres, ``base``.
            depths: deepest push past the undeformed top, metres (a scalar or array: its max).
            speed: m/s.
            hold: s.
            standoff: m.
            tare_time: s of samples before motion; the force is tared on their median.
            retract: also simulate the retraction (False: stop after the hold).

        Returns:
            The trace in cell units; ``depth`` and ``target`` measured from the top at ``xy``.

        Raises:
            InvalidInput: non-positive speed or depth.
            NotConverged: see :meth:`drive`.

        """
        depth = float(np.max(depths))
        if not (depth > 0 and speed > 0):
            raise InvalidInput(f'poke: depth and speed must be > 0, got {depth}, {speed}')
        top = self.top_height(xy)
        start = np.array([xy[0], xy[1], top + standoff])
        self.place_pusher(start, np.array([0.0, 0.0, -1.0]))
        dt = self.config.time_step
        n_tare = max(3, int(round(tare_time / dt)))
        travel = standoff + depth
        n_push = int(np.ceil(travel / (speed * dt)))
        n_hold = int(round(hold / dt))
        push = np.minimum(np.arange(1, n_push + 1) * speed * dt, travel)
        back = push[::-1] if retract else np.zeros(0)
        target = np.concatenate([np.zeros(n_tare), push, np.full(n_hold, travel), back])
        pos, force = self.drive(target)
        force = force - np.median(force[:n_tare])
        width = int(round(self.config.force_window / dt))
        if width > 1:
            kernel = np.ones(width)
            force = (np.convolve(force, kernel, mode='same')
                     / np.convolve(np.ones_like(force), kernel, mode='same'))
        t = np.arange(len(target)) * dt
        return PokeTrace(t=t, depth=pos - standoff, force=force, target=target - standoff)

    def close(self) -> None:
        """Disconnect the engine and remove temporary files."""
        if self.client is not None and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = None
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self):
        """Return the scene."""
        return self

    def __exit__(self, *exc):
        """Close the scene."""
        self.close()


def deformed_nodes(scene: ReplicaScene) -> np.ndarray:
    """Return the soft body's current node positions (N, 3), metres, ``base`` (cell units).

    The order is the mesh's node order (PyBullet keeps the VTK's node order).
    """
    _, nodes = pb.getMeshData(scene.body_id, flags=pb.MESH_DATA_SIMULATION_MESH,
                              physicsClientId=scene.client)
    return np.asarray(nodes, dtype=float) / scene.config.scale
