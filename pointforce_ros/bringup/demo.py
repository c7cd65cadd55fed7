"""``pointforce demo`` (``make demo``): the whole job on the simulated cell, through ROS.

1. Start the cell: the RTDE controller emulator (FEM object ``lamb`` with the ``realistic``
   scenario's sensor effects), the simulated camera and the four product nodes.
2. Capture the equilibrium surface from two camera views (``cloud_capture``).
3. Poke: the first poke at the object's centre, then each next location from
   ``/stiffness_learner/suggest_poke``; every poke goes through the Poke action, ``ur_rtde`` and
   the emulator, lands as an MCAP bag, and the learner refits and the contact service hot-swaps.
4. Query like a planner: a sphere, a line paddle and a cylinder at several poses through
   ``/contact_wrench/contact_wrench``, printed against the FEM ground truth with the error.
5. Plots (PNG): force-displacement curves with the model, the stiffness map against the truth,
   the deformed surface under the sphere.

Ground truth for the queries is the full nonlinear FEM solve, precomputed by
``data/fem/make_demo_queries.py`` into ``data/fem/demo_queries_<object>.npz`` (minutes
per query; the demo itself runs in a few minutes).
"""

import time
from pathlib import Path

import numpy as np
from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup import plots
from pointforce_ros.bringup.cell import CellSession
from pointforce_ros.contact.identify import identify_shape_constant_from_probe
from pointforce_ros.paths import share_path
from pointforce_ros.errors import PointforceError
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.sim.fem.live import LiveContact
from pointforce_ros.sim.fem.probes import cylinder_probe, paddle_probe, pose_for_push, sphere_probe
from pointforce_ros.types import PokeGoal

DATA = share_path('data', 'fem')


def demo_query_set(spec):
    """Return the demo's planner queries as (name, mesh, pose, approach, torque centre) tuples.

    Probes follow the UR TCP convention of :mod:`pointforce_ros.sim.fem.probes`: the mesh's +z
    axis is the push direction and its working end is at the origin.
    """
    cx, cy = spec.centre
    down = np.array([0.0, 0.0, -1.0])
    queries = []
    shapes = [('sphere r20', sphere_probe(0.02), 0.0),
              ('paddle 60 mm', paddle_probe(), 0.4),
              ('cylinder r10', cylinder_probe(), 1.2)]
    offsets = [(0.0, 0.0), (0.015, -0.01), (-0.015, 0.012)]
    for name, mesh, roll in shapes:
        for k, (dx, dy) in enumerate(offsets):
            x, y = cx + dx, cy + dy
            top = np.asarray(spec.top_point(x, y))
            depth = 0.004 if name.startswith('sphere') else 0.003
            pose = pose_for_push(top + down * depth, down, roll + 0.5 * k)
            queries.append((f'{name} #{k + 1}', mesh, pose, down, pose.position))
    return queries


CALIBRATION_OFFSET = (-0.02, -0.012)
"""Where the calibration pushes press, relative to the object's centre (x, y), metres."""

CALIBRATION_DEPTHS = (0.003, 0.005)
"""Depths of the calibration sphere below the top surface, metres."""

ROD_DEPTHS = (0.002, 0.004)
"""Depths of the calibration rod below the top surface, metres."""

ROD_LENGTH = 0.03
"""Length of the calibration rod (a cylinder of radius 10 mm lying along x), metres."""


def calibration_push(spec):
    """Return the demo's calibration push with a second probe: ``(mesh, poses, depths)``.

    A 20 mm sphere pushed straight down at :data:`CALIBRATION_OFFSET` from the centre (away
    from every planner query of :func:`demo_query_set`) to :data:`CALIBRATION_DEPTHS`. Its
    measured force fixes the shape constant ``c`` (``identify_shape_constant_from_probe``).
    """
    cx, cy = spec.centre
    top = np.asarray(spec.top_point(cx + CALIBRATION_OFFSET[0], cy + CALIBRATION_OFFSET[1]))
    down = np.array([0.0, 0.0, -1.0])
    poses = [pose_for_push(top + down * d, down, 0.0) for d in CALIBRATION_DEPTHS]
    return sphere_probe(0.02), poses, np.array(CALIBRATION_DEPTHS)


def calibration_rod_push(spec):
    """Return the demo's second calibration push, a rod: ``(mesh, poses, depths)``.

    A cylinder of radius 10 mm and :data:`ROD_LENGTH` lying along x, pushed straight down at
    the sphere's site (:data:`CALIBRATION_OFFSET`, where the first poke lands) to
    :data:`ROD_DEPTHS`. The sphere shares displacement over a small disc, the rod over a line
    ten times longer: the two together determine both ``c`` and the tail's decay length ``L``
    (one push with one probe fixes only a curve of ``(c, L)`` pairs).
    """
    cx, cy = spec.centre
    top = np.asarray(spec.top_point(cx + CALIBRATION_OFFSET[0], cy + CALIBRATION_OFFSET[1]))
    down = np.array([0.0, 0.0, -1.0])
    poses = [pose_for_push(top + down * d, down, 0.0) for d in ROD_DEPTHS]
    return cylinder_probe(0.01, ROD_LENGTH), poses, np.array(ROD_DEPTHS)


CALIBRATIONS = {'sphere': ('demo_calibration_{}.npz', calibration_push),
                'rod': ('demo_calibration_rod_{}.npz', calibration_rod_push)}
"""Calibration pushes of the demo: name -> (fixture file pattern, push builder)."""


def _calibrate(cell, spec):
    """Identify ``c`` from the calibration push (second probe); None if it cannot be done."""
    path = DATA / f'demo_calibration_{spec.name}.npz'
    if not path.exists():
        print(f'[demo] no calibration push for {spec.name} ({path.name}): c stays as set')
        return None
    mesh, poses, depths = calibration_push(spec)
    with np.load(path, allow_pickle=False) as z:
        if not np.allclose(z['depths'], depths):
            print(f'[demo] {path.name} is for other depths: c stays as set')
            return None
        measured = np.asarray(z['force'], dtype=float)
    server = WrenchServer()
    server.load(cell.models[-1].model_path)
    simulator = server.simulator()
    try:
        fit = identify_shape_constant_from_probe(simulator, mesh, poses, [0.0, 0.0, -1.0],
                                                 measured[:, 2])
    except PointforceError as exc:
        print(f'[demo] calibration failed ({exc}): c stays as set')
        return None
    print(f'[demo] calibration push (20 mm sphere at {1e3 * depths[0]:.0f} and '
          f'{1e3 * depths[-1]:.0f} mm, {", ".join(f"{f:.2f}" for f in measured[:, 2])} N '
          f'measured): identified c = {1e3 * fit.c:.2f} mm (fit RMSE {fit.rmse:.2f} N)')
    return fit


def _ask(cell, queries, gt, verbose: bool):
    """Ask the contact service every query; return (force RMSE or None, first answer)."""
    from geometry_msgs.msg import Vector3
    from pointforce_interfaces.srv import ContactWrench

    if verbose:
        print(f'[demo] {"query":16s} {"pred Fz (N)":>11s} {"true Fz":>8s} {"|dF| (N)":>9s} '
              f'{"|dT| (mN m)":>11s} {"contacts":>8s}')
    errors, first = [], None
    for i, (name, mesh, pose, approach, tc) in enumerate(queries):
        request = ContactWrench.Request(
            mesh=mesh_to_msg(mesh), pose=pose_to_msg(pose),
            approach=Vector3(x=float(approach[0]), y=float(approach[1]), z=float(approach[2])),
            torque_centre=to_point(tc), return_displacements=(i == 0))
        answer = cell.call(cell.wrench_client, request, 60, 'contact_wrench')
        if not answer.success:
            raise RuntimeError(f'contact_wrench refused {name}: {answer.message}')
        f = np.array([answer.wrench.force.x, answer.wrench.force.y, answer.wrench.force.z])
        m = np.array([answer.wrench.torque.x, answer.wrench.torque.y, answer.wrench.torque.z])
        first = answer if i == 0 else first
        if gt is not None:
            df = float(np.linalg.norm(f - gt['force'][i]))
            dm = float(np.linalg.norm(m - gt['torque'][i]))
            errors.append((df, float(np.linalg.norm(gt['force'][i]))))
            if verbose:
                print(f'[demo] {name:16s} {f[2]:11.2f} {gt["force"][i][2]:8.2f} {df:9.2f} '
                      f'{1e3 * dm:11.1f} {answer.contact_count:8d}')
        elif verbose:
            print(f'[demo] {name:16s} {f[2]:11.2f} {"-":>8s} {"-":>9s} {"-":>11s} '
                  f'{answer.contact_count:8d}')
    if not errors:
        return None, first
    rms = float(np.sqrt(np.mean([e[0] ** 2 for e in errors])))
    if verbose:
        peak = max(e[1] for e in errors)
        print(f'[demo] force RMSE over {len(errors)} queries: {rms:.2f} N '
              f'({100 * rms / peak:.0f} % of the largest true force, {peak:.1f} N)')
    return rms, first


def _ground_truth(spec, queries):
    path = DATA / f'demo_queries_{spec.name}.npz'
    if not path.exists():
        return None, path
    with np.load(path, allow_pickle=False) as z:
        gt = {'force': z['force'], 'torque': z['torque'], 'names': list(z['names'])}
    if gt['names'] != [q[0] for q in queries]:
        return None, path
    return gt, path


def run_demo(out: str = 'out/demo', quick: bool = False, object_name: str = 'lamb',
             scenario: str = 'realistic', pokes: int = 0) -> int:
    """Run the demo; returns a process exit code."""
    started = time.monotonic()
    out = Path(out)
    pokes = pokes or (4 if quick else 8)
    cell_dir = out / 'cell'
    if cell_dir.exists() and any(cell_dir.iterdir()):
        # the learner learns from every poke in its store: start clean, keep the old run
        kept = out / time.strftime('cell-previous-%Y%m%d-%H%M%S')
        cell_dir.rename(kept)
        print(f'[demo] an earlier run is in {cell_dir}: moved to {kept} (nothing deleted)')
    print(f'[demo] simulated cell: object {object_name}, scenario {scenario}, {pokes} pokes -> '
          f'{out}')
    with CellSession(out / 'cell', object_name=object_name, scenario=scenario) as cell:
        spec = cell.spec.spec
        surface = cell.capture_surface(views=2)
        print(f'[demo] equilibrium surface: {len(surface)} points '
              f'({time.monotonic() - started:.0f} s)')
        # The first poke lands where the calibration sphere will push: the point model is then
        # conditioned there, and the push measures the contact coupling (c), not the point
        # model's error at an unpoked spot (which c would otherwise absorb).
        if (DATA / f'demo_calibration_{spec.name}.npz').exists():
            first = 'calibration site'
            site = np.asarray(spec.centre, dtype=float) + CALIBRATION_OFFSET
        else:
            first, site = 'object centre', np.asarray(spec.centre, dtype=float)
        gap = np.linalg.norm(surface.points[:, :2] - site, axis=1)
        index = int(np.argmin(np.where(surface.normals[:, 2] > 0.7, gap, np.inf)))
        for k in range(pokes):
            if k > 0 and not cell.models:
                # no model yet: the earlier pokes were not learned from (e.g. aborted on a
                # stalled stream); the arm retracted, so poke the first site again
                why = f'{first} again: no model yet'
            elif k > 0:
                suggestion = cell.suggest(1)
                if not suggestion.success:
                    raise RuntimeError(f'suggest_poke failed: {suggestion.message}')
                index = int(suggestion.surface_indices[0])
                why = f'suggested (model std {suggestion.uncertainty[0]:.2f} N)'
            else:
                why = first
            goal = PokeGoal(point=surface.points[index], normal=surface.normals[index],
                            surface_index=index, force_limit=float(spec.force_cap),
                            depth_limit=float(spec.max_depth), speed=0.004, standoff=0.006)
            result = cell.poke(poke_goal_to_msg(goal))
            line = (f'[demo] poke {k + 1}/{pokes} at surface point {index} ({why}): '
                    f'{result.outcome}, peak {result.peak_force:.2f} N at '
                    f'{1e3 * result.max_depth:.1f} mm, {result.samples} samples')
            status, reason = (cell.wait_learned(result.poke_id) if result.poke_id
                              else (None, result.message))
            if status is not None:
                line += (f'; model v{status.version}, train RMSE {status.training_rmse:.3f} N, '
                         f'prequential RMSE {status.validation_rmse:.3f} N')
            else:
                line += f'; not learned from: {reason}'
            print(line)
        queries = demo_query_set(spec)
        gt, gt_path = _ground_truth(spec, queries)
        print(f'[demo] planner queries through /contact_wrench/contact_wrench '
              f'(ground truth: {"FEM full solve, " + gt_path.name if gt else "not available"})')
        c_eye = float(cell.learner_node.shape_constant)
        rms_eye, _ = _ask(cell, queries, gt, verbose=False)
        if rms_eye is not None:
            print(f'[demo] with c = {1e3 * c_eye:.1f} mm picked by eye (seed 000): force RMSE '
                  f'{rms_eye:.2f} N over {len(queries)} queries')
        fit = _calibrate(cell, spec)
        if fit is not None:
            # the learner saves the next version as it accepts the parameter, and the service
            # may swap to it before set_parameter returns: take the target version first
            target = max(m.version for m in cell.models) + 1
            cell.set_parameter('stiffness_learner', 'shape_constant', float(fit.c))
            cell.wait_model(target)
        _, sphere_answer = _ask(cell, queries, gt, verbose=True)
        learner = cell.learner_node.learner
        model = learner.model
        figures = out / 'figures'
        plots.plot_force_curves(learner.curves, model, surface, figures / 'force_curves.png',
                                title=f'{object_name}: measured loading curves and the model')
        depth = 0.003
        baked = model.bake(surface, np.array([depth - 1e-4, depth]))
        truth = None
        try:
            live = LiveContact.load(spec.name, build=False)
            truth = np.array([live.normal_force(p[0], p[1], depth) for p in surface.points])
        except Exception as exc:  # the map without truth is still worth drawing
            print(f'[demo] no ground-truth stiffness map: {exc}')
        plots.plot_stiffness_map(surface, baked.forces[:, 1], figures / 'stiffness_map.png',
                                 depth=depth, pokes=model.poke_points, truth=truth,
                                 title=f'{object_name}: force at')
        if sphere_answer is not None and len(sphere_answer.displacements):
            u = np.zeros(len(surface))
            u[np.asarray(sphere_answer.displaced_indices, dtype=int)] = \
                sphere_answer.displacements
            plots.plot_deformed_surface(surface, u, figures / 'deformed_surface.png',
                                        title=f'{object_name} under {queries[0][0]}')
        print(f'[demo] figures: {", ".join(sorted(p.name for p in figures.glob("*.png")))} in '
              f'{figures}')
        print(f'[demo] poke bags (rosbag2 MCAP): {cell.paths["store"]}; models: '
              f'{cell.paths["models"]}')
    print(f'[demo] done in {time.monotonic() - started:.0f} s')
    return 0
