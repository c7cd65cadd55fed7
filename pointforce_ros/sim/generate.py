"""``pointforce cell generate``: measured-like data sets from the simulated cell.

For one object and scenario it writes, under ``out``:

* ``scans/`` a rosbag2 MCAP bag of the depth camera's PointCloud2 frames (realsense-ros layout,
  ``camera_depth_optical_frame``) and the camera poses (``/camera/pose``, ``base``);
* ``surface.npz`` the equilibrium surface built from those scans (crop, voxel, outliers,
  outward normals);
* ``pokes/`` a poke store: one rosbag2 MCAP bag per point-probe poke (the poke server's topics,
  250 Hz), made offline by :func:`pointforce_ros.sim.session.simulate_campaign` against the FEM
  live contact path with the scenario's effects;
* ``probes.npz`` + ``probes.json`` line and cylinder probe trials at random orientations with
  their ground-truth force and torque from the full nonlinear FEM solve;
* ``manifest.json`` what was generated, with the seed.

Same seed, same arrays (and the same MCAP bytes: message times come from the simulation clock).
"""

import json
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.pokes.store import PokeStore, TYPESTORE
from pointforce_ros.rotations import matrix_to_quaternion
from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.model.files import save_surface
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.sim.fem.indentation import solve_indentation
from pointforce_ros.sim.fem.live import LiveContact
from pointforce_ros.sim.fem.probes import cylinder_probe, paddle_probe, pose_for_push
from pointforce_ros.sim.objects import load_object
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.sim.session import CellObject, simulate_campaign
from pointforce_ros.surface.equilibrium import build_equilibrium_surface, Scan, SurfaceConfig
from pointforce_ros.pokes.trials import save_probe_trials

PROBE_KINDS = ('point', 'line', 'cylinder')
MIN_PROBE_STEPS = 3
"""Fewest solved steps a probe trial keeps when a deeper step does not converge."""
SCAN_TOPIC = '/camera/camera/depth/color/points'
CAMERA_POSE_TOPIC = '/camera/pose'


class Progress:
    """A text progress bar on one line per update: ``[generate] pokes  7/20 ...  ETA 12 s``."""

    def __init__(self, label: str, total: int, say: Callable[[str], None] = print):
        """Start timing ``total`` steps of ``label``."""
        self.label, self.total, self.say = label, max(int(total), 1), say
        self.start = time.monotonic()
        self.done = 0

    def step(self, note: str = '') -> None:
        """Count one step and print the bar."""
        self.done += 1
        elapsed = time.monotonic() - self.start
        eta = elapsed / self.done * (self.total - self.done)
        width = 24
        fill = int(width * self.done / self.total)
        self.say(f'[generate] {self.label:9s} [{"#" * fill}{"." * (width - fill)}] '
                 f'{self.done}/{self.total} {elapsed:6.1f} s, ETA {eta:5.0f} s {note}')


def fem_cell_object(spec, live, margin: float = 0.25):
    """:class:`~pointforce_ros.sim.session.CellObject` of a FEM object and its live path.

    Pokes are drawn over the footprint inset by ``margin`` (fraction of the half size); on a
    dome, over the box inscribed in the footprint ellipse shrunk by ``margin`` (the bounding
    box's corners lie on the steep rim, where a poke meets the side before the commanded point).
    """

    def surface_at(xy):
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        points = np.array([spec.top_point(x, y) for x, y in xy])
        normals = np.array([spec.top_normal(x, y) for x, y in xy])
        return points, normals

    cx, cy = spec.centre
    hx, hy = spec.size[0] / 2 * (1 - margin), spec.size[1] / 2 * (1 - margin)
    if spec.kind == 'dome':
        hx, hy = hx / np.sqrt(2.0), hy / np.sqrt(2.0)
    return CellObject(clean=live.point_probe_wrench, surface_at=surface_at,
                      region=((cx - hx, cx + hx), (cy - hy, cy + hy)), name=spec.name)


def _stamp(t: float):
    sec = int(np.floor(t))
    return TYPESTORE.types['builtin_interfaces/msg/Time'](
        sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


def write_scans_bag(frames: Sequence, path) -> Path:
    """Write camera frames (organised, optical frame) and their poses as a rosbag2 MCAP bag."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    t = TYPESTORE.types
    path = Path(path)
    if path.exists():
        raise InvalidInput(f'{path} exists already')
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        cloud_conn = writer.add_connection(SCAN_TOPIC, 'sensor_msgs/msg/PointCloud2',
                                           typestore=TYPESTORE)
        pose_conn = writer.add_connection(CAMERA_POSE_TOPIC, 'geometry_msgs/msg/PoseStamped',
                                          typestore=TYPESTORE)
        for frame in frames:
            stamp = _stamp(frame.stamp)
            points = np.asarray(frame.points, dtype=np.float32)
            height, width = points.shape[:2] if points.ndim == 3 else (1, len(points))
            rgb = np.clip(np.round(np.asarray(frame.rgb) * 255), 0, 255).astype(np.uint32)
            packed = ((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]).astype('<u4')
            rec = np.zeros(height * width, dtype=np.dtype(
                {'names': ['x', 'y', 'z', 'rgb'], 'formats': ['<f4', '<f4', '<f4', '<u4'],
                 'offsets': [0, 4, 8, 16], 'itemsize': 20}))
            flat = points.reshape(-1, 3)
            rec['x'], rec['y'], rec['z'] = flat[:, 0], flat[:, 1], flat[:, 2]
            rec['rgb'] = packed.reshape(-1)
            fields = [t['sensor_msgs/msg/PointField'](name=n, offset=o, datatype=7, count=1)
                      for n, o in (('x', 0), ('y', 4), ('z', 8), ('rgb', 16))]
            msg = t['sensor_msgs/msg/PointCloud2'](
                header=t['std_msgs/msg/Header'](stamp=stamp, frame_id=frame.frame),
                height=height, width=width, fields=fields, is_bigendian=False, point_step=20,
                row_step=20 * width, data=np.frombuffer(rec.tobytes(), dtype=np.uint8),
                is_dense=False)
            t_ns = int(round(frame.stamp * 1e9))
            writer.write(cloud_conn, t_ns,
                         TYPESTORE.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2'))
            q = matrix_to_quaternion(frame.camera_pose[:3, :3])
            p = frame.camera_pose[:3, 3]
            pose = t['geometry_msgs/msg/PoseStamped'](
                header=t['std_msgs/msg/Header'](stamp=stamp, frame_id='base'),
                pose=t['geometry_msgs/msg/Pose'](
                    position=t['geometry_msgs/msg/Point'](x=p[0], y=p[1], z=p[2]),
                    orientation=t['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2],
                                                                  w=q[3])))
            writer.write(pose_conn, t_ns,
                         TYPESTORE.serialize_cdr(pose, 'geometry_msgs/msg/PoseStamped'))
    return path


def scan_object(spec, scenario, views: int = 2, seed: int = 0, distance: float = 0.35):
    """Render ``views`` camera frames of the object; returns (frames, Scan list)."""
    mesh, rgb = spec.surface_mesh()
    target = np.array([spec.centre[0], spec.centre[1], spec.size[2]])
    frames, scans = [], []
    for i, pose in enumerate(ring_viewpoints(target, distance, count=views)):
        kwargs = scenario.camera_kwargs(i)
        kwargs['seed'] = int(kwargs['seed']) + int(seed)
        frame = DepthCamera(**kwargs).render(mesh, pose, rgb=rgb, organised=True,
                                             stamp=float(i))
        frames.append(frame)
        valid = np.all(np.isfinite(frame.points), axis=-1)
        scans.append(Scan(points=frame.points[valid], colors=frame.rgb[valid],
                          transform=frame.camera_pose))
    return frames, scans


def probe_trials(spec, kinds: Sequence[str], count: int, seed: int,
                 progress: Callable[[str], None] = print, steps: int = 8,
                 max_tilt_deg: float = 15.0, done: Sequence[Dict] = (),
                 on_trial: Optional[Callable[[List[Dict]], None]] = None) -> List[Dict]:
    """Line / cylinder probe trials at random locations and orientations with FEM ground truth.

    Each trial pushes the probe along a direction tilted up to ``max_tilt_deg`` from straight
    down, with a random roll about it, from just touching the undeformed top to
    ``spec.max_depth`` in ``steps`` steps (full nonlinear solve at ``spec.mesh_live``); the
    push ends at the first step past 1.5 x the object's force cap, and that step is dropped. A
    step whose full solve does not converge ends the push there: the steps before it are kept
    (with a progress line), and a trial with fewer than :data:`MIN_PROBE_STEPS` solved steps
    is skipped (the other trials are kept).

    Resuming: ``done`` holds trials an interrupted run already solved (in order, as this
    passed them to ``on_trial``, None for a skipped one); their poses are drawn again, so the
    rest are the same as in an uninterrupted run, but they are not solved again. ``on_trial``
    is called after each trial with the list so far, None marking a skipped trial (to save
    partial work).
    """
    rng = np.random.default_rng([int(seed), 7])
    makers = {'line': paddle_probe, 'cylinder': cylinder_probe}
    plan = [k for k in kinds if k in makers for _ in range(int(count))]
    bar = Progress('probes', len(plan), progress)
    trials = []
    done = list(done)
    for index, kind in enumerate(plan):
        mesh = makers[kind]()
        cx, cy = spec.centre
        x = cx + rng.uniform(-0.2, 0.2) * spec.size[0]
        y = cy + rng.uniform(-0.2, 0.2) * spec.size[1]
        tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
        azimuth = rng.uniform(0.0, 2 * np.pi)
        direction = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                              -np.cos(tilt)])
        roll = rng.uniform(0.0, np.pi)
        top = np.asarray(spec.top_point(x, y))
        pose = pose_for_push(top, direction, roll)
        # dense samples, not vertices: a cylinder's side between its end rings can reach
        # a dome's apex while every vertex is still above the surface
        world = pose.apply(sample_mesh_surface(mesh, 0.001)[0])
        over = spec.footprint_mask(world[:, 0], world[:, 1])
        heights = np.asarray(spec.top_height(world[over, 0], world[over, 1]))
        clearance = float(np.max((heights - world[over, 2]) / np.cos(tilt))) if np.any(over) \
            else 0.0
        start = pose_for_push(top - direction * (clearance + 0.0005), direction, roll)
        depths = np.linspace(0.0, spec.max_depth + clearance + 0.0005, steps + 1)[1:]
        if index < len(done):
            trials.append(done[index])
            bar.step(f'{kind}: solved before (resumed)')
            continue
        began = time.monotonic()
        try:
            # a step that fails deep in the push keeps the steps solved before it
            result = solve_indentation(spec, mesh, start, direction, depths,
                                       torque_centre=start.position, h=spec.mesh_live,
                                       stop_force=1.5 * spec.force_cap, keep_solved=True)
            if len(result.depths) < min(MIN_PROBE_STEPS, len(depths)):
                raise NotConverged(f'only {len(result.depths)} of {len(depths)} steps solved')
        except NotConverged as exc:
            # one hard pose must not cost the trials already solved (minutes each)
            bar.step(f'{kind}: skipped, the full solve did not converge ({exc})')
            trials.append(None)
            if on_trial is not None:
                on_trial(trials)
            continue
        normal_force = -(result.force @ direction)
        if len(result.depths) < len(depths) and normal_force[-1] <= 1.5 * spec.force_cap:
            progress(f'[probes] {kind}: the full solve did not converge past '
                     f'{1e3 * result.depths[-1]:.1f} mm; kept its {len(result.depths)} '
                     f'steps to there')
        keep = normal_force <= 1.5 * spec.force_cap
        keep[0] = True
        depths = result.depths
        trials.append({
            'kind': kind, 'vertices': mesh.vertices, 'triangles': mesh.triangles,
            'start_position': start.position, 'orientation': start.orientation,
            'direction': direction, 'torque_centre': start.position,
            'depths': result.depths[keep], 'force': result.force[keep],
            'torque': result.torque[keep], 'seconds': time.monotonic() - began})
        bar.step(f'{kind}: {normal_force[keep][-1]:.1f} N at {1e3 * depths[keep][-1]:.1f} mm')
        if on_trial is not None:
            on_trial(trials)
    return [t for t in trials if t is not None]


def generate(object_name: str, scenario_name: str, pokes: int, probes: Sequence[str],
             seed: int, out, progress: Callable[[str], None] = print,
             probe_count: int = 3) -> dict:
    """Generate the data set; returns the manifest (also written to ``manifest.json``)."""
    unknown = set(probes) - set(PROBE_KINDS)
    if unknown:
        raise InvalidInput(f'--probes: unknown kind(s) {sorted(unknown)}; use {PROBE_KINDS}')
    if pokes < 0:
        raise InvalidInput(f'--pokes must be >= 0, got {pokes}')
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise InvalidInput(f'{out} is not empty: choose a new --out directory')
    out.mkdir(parents=True, exist_ok=True)
    spec = load_object(object_name)
    scenario = load_scenario(scenario_name)
    started = time.monotonic()
    frames, scans = scan_object(spec, scenario, seed=seed)
    write_scans_bag(frames, out / 'scans')
    lo = np.array([spec.centre[0] - spec.size[0] / 2 - 0.005,
                   spec.centre[1] - spec.size[1] / 2 - 0.005, 0.004])
    hi = np.array([spec.centre[0] + spec.size[0] / 2 + 0.005,
                   spec.centre[1] + spec.size[1] / 2 + 0.005, spec.size[2] + 0.02])
    surface, report = build_equilibrium_surface(scans, SurfaceConfig(roi_min=lo, roi_max=hi))
    save_surface(surface, out / 'surface.npz')
    progress(f'[generate] surface: {len(surface)} points from {len(scans)} scans')
    records = []
    if 'point' in probes and pokes:
        progress(f'[generate] {spec.name}: loading the FEM live contact path (built on first '
                 'use, minutes)')
        live = LiveContact.load(spec.name, progress=progress)
        bar = Progress('pokes', pokes, progress)
        obj = fem_cell_object(spec, live)
        records = simulate_campaign(obj, scenario, count=pokes, seed=seed,
                                    force_limit=spec.force_cap, depth_limit=spec.max_depth)
        store = PokeStore(out / 'pokes')
        for record in records:
            store.add(record)
            bar.step(f'{record.poke_id}: peak {record.normal_force().max():.2f} N')
    trials = probe_trials(spec, [k for k in probes if k != 'point'], probe_count, seed,
                          progress) if set(probes) - {'point'} else []
    if trials:
        save_probe_trials(trials, out)
    manifest = {'object': spec.name, 'scenario': scenario_name, 'seed': int(seed),
                'pokes': len(records), 'probe_trials': len(trials),
                'surface_points': len(surface), 'scans': len(frames),
                'seconds': round(time.monotonic() - started, 1)}
    (out / 'manifest.json').write_text(json.dumps(manifest, indent=1))
    progress(f'[generate] done in {manifest["seconds"]} s -> {out}')
    return manifest


def run_generate(object_name: str, scenario: str, pokes: int, probes: Sequence[str], seed: int,
                 out) -> int:
    """CLI body of ``pointforce cell generate``."""
    generate(object_name, scenario, pokes, probes, seed, out)
    return 0
