"""Offline, deterministic cell sessions: point pokes run against a cell force model, no ROS.

:func:`simulate_poke` moves the probe tip exactly as the poke server does (stand-off hold, tare,
constant-speed push along ``-normal`` until the force or depth limit, optional hold, retraction
at the same speed) and samples ``force_model.wrench(tcp_pose6, t)`` at the streaming rate, so a
:class:`~pointforce_ros.types.PokeRecord` comes out as the server would have persisted it.
:func:`simulate_campaign` runs a sequence of pokes on one object with one stateful force model
(F/T drift, material history and plastic set carry over from poke to poke), placing the poke
points where the scenario's depth camera would have seen the surface (bias and noise).

Conventions: SI units, ``base`` frame; the TCP is the probe tip and its +z axis is the push
direction ``-normal`` (what :class:`~pointforce_ros.sim.scenario.CellForceModel` expects).
"""

from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.sim.ft_sensor import FtSensor
from pointforce_ros.sim.scenario import CleanFn, HalfSpaceContact, Scenario
from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import rotvec_aligning_z
from pointforce_ros.types import as_array, PokeRecord, unit_rows
from pointforce_ros.sim.fem.live import LiveContact

SurfaceFn = Callable[[np.ndarray], Tuple[np.ndarray, np.ndarray]]


def simulate_poke(force_model, point, normal, *, poke_id: str, speed: float = 0.002,
                  standoff: float = 0.01, force_limit: float = 5.0, depth_limit: float = 0.015,
                  rate: float = 250.0, t0: float = 0.0, hold: float = 0.0, seed: int = 0,
                  pre_hold: float = 0.1, tare: bool = True, wall_offset: float = 0.0,
                  wall_jitter: float = 0.0005, meta: Optional[dict] = None) -> PokeRecord:
    """Run one point poke against ``force_model`` and return its record.

    Tip path (controller clock, sample ``k`` at ``t0 + k / rate``): hold at
    ``point + standoff * normal`` for ``pre_hold`` seconds, tare the F/T sensor on the last hold
    sample ("right before the push"), push along ``-normal`` at ``speed`` until the reported
    normal force reaches ``force_limit`` or the displacement past ``point`` reaches
    ``depth_limit``, hold there for ``hold`` seconds, retract at ``speed`` to the stand-off.

    Args:
        force_model: object with ``wrench(tcp_pose6 (6,), t) -> (6,)`` and ``tare(t)`` (a
            :class:`~pointforce_ros.sim.scenario.CellForceModel`); ``reset_poke()`` is called
            at the end when it exists.
        point: (3,) commanded surface point, metres, ``base`` (as the camera saw it).
        normal: (3,) unit outward normal at ``point``, ``base``.
        poke_id: id of the record.
        speed: push and retraction speed, m/s.
        standoff: start distance along ``normal``, metres.
        force_limit: stop pushing at this normal force, N.
        depth_limit: stop pushing at this displacement past ``point``, metres.
        rate: streaming rate, Hz (one force-model call per sample).
        t0: controller time of the first sample, seconds.
        hold: dwell at the turning point, seconds.
        seed: seed of the ROS-time receive jitter.
        pre_hold: dwell at the stand-off before the push (the tare is at its end), seconds.
        tare: tare the sensor before the push (False: raw sensor offset stays in the data).
        wall_offset: ROS time minus controller time, seconds.
        wall_jitter: receive latency added to the ROS time, uniform in [0, jitter], seconds.
        meta: extra metadata stored in the record.

    Returns:
        The record; ``meta`` holds ``tare_time`` (controller s, or None), ``tared``,
        ``standoff``, ``hold``, ``force_limit``, ``depth_limit`` and ``rate``.

    Raises:
        InvalidInput: non-unit normal, non-positive speed/rate/limits, negative stand-off/hold.

    """
    point = as_array(point, 'simulate_poke.point', (3,))
    normal = unit_rows(as_array(normal, 'simulate_poke.normal', (3,)), 'simulate_poke.normal')
    for name, value in (('speed', speed), ('rate', rate), ('force_limit', force_limit),
                        ('depth_limit', depth_limit)):
        if not (np.isfinite(value) and value > 0):
            raise InvalidInput(f'simulate_poke.{name}: must be > 0, got {value}')
    for name, value in (('standoff', standoff), ('hold', hold), ('pre_hold', pre_hold),
                        ('wall_jitter', wall_jitter)):
        if not (np.isfinite(value) and value >= 0):
            raise InvalidInput(f'simulate_poke.{name}: must be >= 0, got {value}')
    if not np.isfinite(t0):
        raise InvalidInput(f'simulate_poke.t0: must be finite, got {t0}')
    dt = 1.0 / float(rate)
    step = float(speed) * dt
    rotvec = rotvec_aligning_z(-normal)
    poses: List[np.ndarray] = []
    wrenches: List[np.ndarray] = []
    times: List[float] = []

    def sample(d: float) -> np.ndarray:
        t = float(t0) + len(times) * dt
        pose = np.concatenate([point - d * normal, rotvec])
        wrench = np.asarray(force_model.wrench(pose, t), dtype=np.float64)
        poses.append(pose)
        wrenches.append(wrench)
        times.append(t)
        return wrench

    d = -float(standoff)
    for _ in range(max(1, int(round(pre_hold * rate)))):
        sample(d)
    tare_time = times[-1] if tare else None
    if tare:
        force_model.tare(tare_time)
    outcome = 'depth_limit'
    while True:
        d_next = min(d + step, float(depth_limit))
        d = d_next
        wrench = sample(d)
        if float(wrench[:3] @ normal) >= force_limit:
            outcome = 'force_limit'
            break
        if d >= depth_limit:
            break
    for _ in range(int(round(hold * rate))):
        sample(d)
    while d > -standoff:
        d = max(d - step, -float(standoff))
        sample(d)
    if hasattr(force_model, 'reset_poke'):
        force_model.reset_poke()
    t_ctrl = np.asarray(times)
    rng = np.random.default_rng(seed)
    t_wall = t_ctrl + float(wall_offset) + rng.uniform(0.0, float(wall_jitter), len(t_ctrl))
    info = dict(meta or {})
    info.update(tare_time=tare_time, tared=bool(tare), standoff=float(standoff),
                hold=float(hold), force_limit=float(force_limit),
                depth_limit=float(depth_limit), rate=float(rate))
    return PokeRecord(poke_id=poke_id, point=point, normal=normal, t=t_wall,
                      t_controller=t_ctrl, tcp_pose=np.asarray(poses),
                      wrench=np.asarray(wrenches), speed=float(speed), probe='point',
                      outcome=outcome, meta=info)


@dataclass(frozen=True)
class CellObject:
    """An object the offline cell can poke: clean contact physics plus its surface.

    Attributes:
        clean: ``clean(tip (3,), axis (3,)) -> (force (3,), torque (3,))``, base frame, N, N m.
        surface_at: ``surface_at(xy (N, 2)) -> (points (N, 3), normals (N, 3))``: the true
            (undeformed) surface above the table positions ``xy``, metres, unit outward normals.
        region: ``((x_min, x_max), (y_min, y_max))`` metres where pokes may be placed.
        name: label stored in the records' metadata.

    """

    clean: CleanFn
    surface_at: SurfaceFn
    region: Tuple[Tuple[float, float], Tuple[float, float]] = ((-0.03, 0.03), (-0.03, 0.03))
    name: str = 'object'


def halfspace_object(contact: Optional[HalfSpaceContact] = None,
                     region=((-0.03, 0.03), (-0.03, 0.03))) -> CellObject:
    """Wrap a :class:`HalfSpaceContact` (flat top at ``z0``, normal +z) as a cell object."""
    contact = contact if contact is not None else HalfSpaceContact()

    def surface_at(xy):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        points = np.column_stack([xy, np.full(len(xy), contact.z0)])
        normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        return points, normals

    return CellObject(clean=contact, surface_at=surface_at, region=tuple(map(tuple, region)),
                      name='halfspace')


def fem_object(object_name: str = 'plush', *, margin: float = 0.012,
               cache_dir: Optional[str] = None) -> CellObject:
    """Wrap the FEM live contact of ``config/objects/<object_name>`` as a cell object.

    The clean physics is ``LiveContact.point_probe_wrench`` (precomputed nonlinear pokes); the
    surface is the object's undeformed top; the poke region is the footprint's bounding box
    shrunk by ``margin`` metres (keeps pokes off the edges).

    Raises:
        DataError: the object's live cache is missing or stale (see ``LiveContact.load``).
        InvalidInput: unknown object, or a margin that leaves no region.

    """
    live = LiveContact.load(object_name, cache_dir=cache_dir, build=False)
    spec = live.spec
    half = np.array(spec.size[:2]) / 2 - float(margin)
    if np.any(half <= 0):
        raise InvalidInput(f'fem_object: margin {margin} m leaves no poke region on '
                           f'{spec.name} (size {spec.size[:2]})')
    centre = np.array(spec.centre, dtype=np.float64)

    def surface_at(xy):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return (np.asarray(spec.top_point(xy[:, 0], xy[:, 1])),
                np.asarray(spec.top_normal(xy[:, 0], xy[:, 1])))

    region = ((centre[0] - half[0], centre[0] + half[0]),
              (centre[1] - half[1], centre[1] + half[1]))
    return CellObject(clean=live.point_probe_wrench, surface_at=surface_at, region=region,
                      name=spec.name)


def as_cell_object(obj) -> CellObject:
    """Return ``obj`` as a :class:`CellObject` (a :class:`HalfSpaceContact` is wrapped).

    Raises:
        InvalidInput: anything else.

    """
    if isinstance(obj, CellObject):
        return obj
    if isinstance(obj, HalfSpaceContact):
        return halfspace_object(obj)
    raise InvalidInput(f'simulate_campaign: object must be a CellObject or HalfSpaceContact, got '
                       f'{type(obj).__name__}')


def _tilted(normals: np.ndarray, tilt_deg, rng: np.random.Generator) -> np.ndarray:
    """Tilt each unit normal by ``tilt_deg`` (scalar or (lo, hi) range) about a random azimuth."""
    bounds = np.broadcast_to(np.asarray(tilt_deg, dtype=np.float64), (2,))
    lo, hi = float(bounds[0]), float(bounds[1])
    n = len(normals)
    angle = np.radians(rng.uniform(lo, hi, n))
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(normals, u)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    lateral = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * w
    out = np.cos(angle)[:, None] * normals + np.sin(angle)[:, None] * lateral
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _speeds(speed, count: int, rng: np.random.Generator) -> np.ndarray:
    if np.ndim(speed) == 0:
        values = np.full(count, float(speed))
    else:
        speed = np.asarray(speed, dtype=np.float64)
        if speed.shape == (2,):
            values = rng.uniform(speed[0], speed[1], count)
        elif speed.shape == (count,):
            values = speed.copy()
        else:
            raise InvalidInput(f'simulate_campaign.speed: a scalar, a (lo, hi) range or one per '
                               f'poke ({count}), got shape {speed.shape}')
    if not np.all(np.isfinite(values) & (values > 0)):
        raise InvalidInput('simulate_campaign.speed: speeds must be > 0 m/s')
    return values


def simulate_campaign(obj, scenario: Scenario, *, points: Optional[Sequence] = None,
                      normals: Optional[Sequence] = None, count: Optional[int] = None,
                      repeats: int = 1, seed: int = 0, speed=0.002, standoff: float = 0.01,
                      force_limit: float = 5.0, depth_limit: float = 0.012, rate: float = 250.0,
                      hold: float = 0.0, gap: float = 2.0, tare: bool = True,
                      normal_tilt_deg=0.0, camera_range: float = 0.5,
                      camera_averaging: int = 16, start_time: float = 0.0,
                      id_prefix: str = 'poke-', surface=None) -> List[PokeRecord]:
    """Poke ``obj`` under ``scenario``: a deterministic list of records (same seed, same arrays).

    Locations are ``points``/``normals`` (true surface positions) or ``count`` positions drawn
    uniformly over ``obj.region``; each is poked ``repeats`` times, interleaved (all locations,
    then all again), with one stateful force model for the whole campaign. The commanded point is
    where the scenario's camera sees the surface: ``depth_bias`` plus noise of standard
    deviation ``(a + b camera_range**2) / sqrt(camera_averaging)`` along ``-normal`` (a camera
    looking down the normal; the equilibrium surface averages ``camera_averaging`` pixels).
    Given the ``surface`` the cell's camera scan produced, the commanded point and normal are
    instead those of its point nearest to each location, as the product pokes: the camera's
    bias, noise and the surface pipeline's smoothing and normal errors all come from the scan.

    Args:
        obj: a :class:`CellObject` or :class:`HalfSpaceContact`.
        scenario: effects and seed (camera, F/T and physical effects are all applied).
        points, normals: (N, 3) true surface points and unit normals, or None.
        count: number of random locations when ``points`` is None.
        repeats: pokes per location (>= 1).
        seed: seed of locations, speeds, tilts, camera noise and F/T noise (mixed with the
            scenario's seed).
        speed: m/s, a scalar, a ``(lo, hi)`` range drawn per poke, or one per poke.
        standoff, force_limit, depth_limit, rate, hold, tare: see :func:`simulate_poke`.
        gap: controller time between the end of one poke and the start of the next, seconds.
        normal_tilt_deg: tilt of the commanded normal away from the true one, degrees (scalar
            or ``(lo, hi)``), random azimuth: oblique pokes (or normal-estimation error).
        camera_range: camera distance for the range-dependent noise term, metres.
        camera_averaging: pixels averaged per surface point (noise / sqrt of it).
        start_time: controller time of the first sample, seconds.
        id_prefix: ids are ``f'{id_prefix}{k:06d}'`` from 1.
        surface: a scanned :class:`~pointforce_ros.types.Surface` (``base``) to take the
            commanded points and normals from, or None for the camera model above.

    Raises:
        InvalidInput: neither or both of ``points`` and ``count``, bad shapes or limits.

    """
    cell = as_cell_object(obj)
    if not isinstance(scenario, Scenario):
        raise InvalidInput(f'simulate_campaign: scenario must be a Scenario, got '
                           f'{type(scenario).__name__}')
    if int(repeats) < 1:
        raise InvalidInput(f'simulate_campaign.repeats: must be >= 1, got {repeats}')
    mixed = np.random.SeedSequence([int(scenario.seed), int(seed)])
    rng_loc, rng_cam, rng_ft, rng_wall = (np.random.default_rng(s) for s in mixed.spawn(4))
    if (points is None) == (count is None):
        raise InvalidInput('simulate_campaign: give either points (with normals) or count')
    if points is None:
        if int(count) < 1:
            raise InvalidInput(f'simulate_campaign.count: must be >= 1, got {count}')
        (x0, x1), (y0, y1) = cell.region
        xy = np.column_stack([rng_loc.uniform(x0, x1, int(count)),
                              rng_loc.uniform(y0, y1, int(count))])
        true_points, true_normals = cell.surface_at(xy)
    else:
        true_points = as_array(points, 'simulate_campaign.points', (None, 3))
        if normals is None:
            raise InvalidInput('simulate_campaign: points need normals')
        true_normals = unit_rows(as_array(normals, 'simulate_campaign.normals',
                                          (len(true_points), 3)), 'simulate_campaign.normals')
    true_points = np.asarray(true_points, dtype=np.float64)
    true_normals = np.asarray(true_normals, dtype=np.float64)
    n_loc = len(true_points)
    order = np.tile(np.arange(n_loc), int(repeats))
    n_pokes = len(order)
    cam = scenario.camera_kwargs()
    sigma = (cam['noise_a'] + cam['noise_b'] * camera_range ** 2) / np.sqrt(
        max(int(camera_averaging), 1))
    observed = true_points - (cam['depth_bias'] + sigma * rng_cam.standard_normal(n_loc)
                              )[:, None] * true_normals
    seen_normals = true_normals
    if surface is not None:
        from scipy.spatial import cKDTree
        facing = np.flatnonzero(np.asarray(surface.normals)[:, 2] > 0.3)
        if len(facing) == 0:
            raise InvalidInput('simulate_campaign: the surface has no upward-facing point')
        _, near = cKDTree(np.asarray(surface.points)[facing]).query(true_points)
        observed = np.asarray(surface.points, dtype=np.float64)[facing[near]]
        seen_normals = np.asarray(surface.normals, dtype=np.float64)[facing[near]]
    commanded_normals = (_tilted(seen_normals, normal_tilt_deg, rng_loc)
                         if np.any(np.asarray(normal_tilt_deg) != 0) else seen_normals)
    speeds = _speeds(speed, n_pokes, rng_loc)
    ft_kwargs = {}
    for eff in scenario.effects:
        if eff.stage == 'ft':
            ft_kwargs.update(eff.ft_kwargs())
    sensor = FtSensor(seed=int(rng_ft.integers(2 ** 31)), **ft_kwargs)
    model = scenario.force_model(cell.clean, ft_sensor=sensor)
    records = []
    t = float(start_time)
    wall_seeds = rng_wall.integers(2 ** 31, size=n_pokes)
    for k, loc in enumerate(order):
        rec = simulate_poke(model, observed[loc], commanded_normals[loc],
                            poke_id=f'{id_prefix}{k + 1:06d}', speed=float(speeds[k]),
                            standoff=standoff, force_limit=force_limit, depth_limit=depth_limit,
                            rate=rate, t0=t, hold=hold, seed=int(wall_seeds[k]), tare=tare,
                            meta={'scenario': scenario.name, 'object': cell.name,
                                  'sequence': k})
        records.append(rec)
        t = float(rec.t_controller[-1]) + float(gap)
    return records
