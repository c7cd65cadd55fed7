"""``pointforce bench ros``: what ROS costs on top of the core, and the live F/T stream quality.

Figures, each against a baseline measured in the same run:

* single ContactWrench round trip over Fast DDS (p50, p99) against the same query called on the
  core directly (``ros_rtt_over_core``);
* batch throughput over ROS (poses/s) against the core's batch call (``batch_ros_over_core``);
* the F/T stream of a poke campaign through the real ur_rtde against the emulator: the rate inside
  the recorded pokes against the 250 Hz target (``ft_rate_over_target``), the rate over the whole
  campaign including the time between pokes, and dropped samples (controller-time gaps).
"""

import os
import tempfile
import time
from pathlib import Path

import numpy as np
from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.shapes import icosphere
from pointforce_ros.sim.rtde.process import start_emulator
from pointforce_ros.types import ContactQuery, PokeGoal, Pose


def _percentiles(values):
    values = np.asarray(values) * 1e3
    return float(np.percentile(values, 50)), float(np.percentile(values, 99))


def bench_ros(quick: bool = False) -> dict:
    """Run the benchmark; returns a JSON-able dict (times in ms unless the key says)."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    from geometry_msgs.msg import Vector3
    from pointforce_interfaces.action import Poke
    from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
    from rclpy.action import ActionClient
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    n_single = 100 if quick else 500
    n_batch = 1000 if quick else 10000
    campaign_s = 10.0 if quick else 60.0
    out = {}
    work = Path(tempfile.mkdtemp(prefix='pointforce-bench-ros-'))
    model = patch_contact_model(spacing=0.002)
    save_model(model, work / 'models')
    sphere = icosphere(0.02, 2)
    rng = np.random.default_rng(0)
    poses = [Pose(position=[0.5 + dx, dy, 0.06 - d]) for dx, dy, d in
             zip(rng.uniform(-0.02, 0.02, n_batch), rng.uniform(-0.015, 0.015, n_batch),
                 rng.uniform(0.0, 0.004, n_batch))]
    centre = np.array([0.5, 0.0, 0.06])
    server = WrenchServer()
    server.swap(model)
    for pose in poses[:5]:  # warm-up: the first query builds the projection cache
        server.answer(ContactQuery(mesh=sphere, poses=(pose,), approach=[0, 0, -1],
                                   torque_centre=centre))
    core = []
    for pose in poses[:n_single]:
        start = time.perf_counter()
        server.answer(ContactQuery(mesh=sphere, poses=(pose,), approach=[0, 0, -1],
                                   torque_centre=centre))
        core.append(time.perf_counter() - start)
    start = time.perf_counter()
    server.answer_batch(ContactQuery(mesh=sphere, poses=tuple(poses), approach=[0, 0, -1],
                                     torque_centre=centre))
    core_batch = time.perf_counter() - start
    with InProcessLauncher() as launcher, InProcessLauncher(threads=2) as planner:
        # the client in its own context, as a planner process would be
        launcher.add(ContactWrenchNode(context=launcher.context, parameter_overrides=[
            Parameter('model_dir', value=str(work / 'models'))]))
        client_node = planner.add(Node('bench_client', context=planner.context))
        single = client_node.create_client(ContactWrench, '/contact_wrench/contact_wrench')
        batch = client_node.create_client(ContactWrenchBatch,
                                          '/contact_wrench/contact_wrench_batch')
        if not (single.wait_for_service(timeout_sec=20)
                and batch.wait_for_service(timeout_sec=20)):
            raise RuntimeError('contact_wrench services did not appear within 20 s')
        mesh_msg = mesh_to_msg(sphere)
        rtt = []
        for pose in poses[:n_single]:
            req = ContactWrench.Request(mesh=mesh_msg, pose=pose_to_msg(pose),
                                        approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                        torque_centre=to_point(centre))
            start = time.perf_counter()
            planner.wait_future(single.call_async(req), 30, 'contact_wrench')
            rtt.append(time.perf_counter() - start)
        req = ContactWrenchBatch.Request(mesh=mesh_msg, poses=[pose_to_msg(p) for p in poses],
                                         approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                         torque_centre=to_point(centre))
        start = time.perf_counter()
        resp = planner.wait_future(batch.call_async(req), 120, 'contact_wrench_batch')
        ros_batch = time.perf_counter() - start
        if not resp.success:
            raise RuntimeError(f'batch refused: {resp.message}')
    p50, p99 = _percentiles(rtt)
    c50, c99 = _percentiles(core)
    out.update(single_rtt_p50_ms=p50, single_rtt_p99_ms=p99, core_query_p50_ms=c50,
               core_query_p99_ms=c99, ros_rtt_over_core=p50 / c50, batch_poses=n_batch,
               batch_ros_s=ros_batch, batch_core_s=core_batch,
               batch_ros_poses_per_s=n_batch / ros_batch,
               batch_ros_over_core=ros_batch / core_batch)

    emulator = start_emulator(work / 'logs',
                              force_model='pointforce_ros.sim.rtde.forces:HalfSpaceSpring',
                              force_model_kwargs={'z0': 0.04, 'k': 1000.0},
                              initial_pose=[0.5, 0.0, 0.1, np.pi, 0.0, 0.0])
    try:
        with InProcessLauncher() as launcher, InProcessLauncher(threads=2) as planner:
            poke_node = launcher.add(PokeServerNode(context=launcher.context, parameter_overrides=[
                Parameter('robot_ip', value=emulator.host),
                Parameter('store_dir', value=str(work / 'pokes'))]))
            client_node = planner.add(Node('bench_poker', context=planner.context))
            client = ActionClient(client_node, Poke, '/poke_server/poke')
            if not client.wait_for_server(timeout_sec=20):
                raise RuntimeError('poke action did not appear within 20 s')
            first = poke_node.samples_streamed
            start = time.monotonic()
            pokes = 0
            while time.monotonic() - start < campaign_s:
                x, y = 0.5 + rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02)
                goal = poke_goal_to_msg(PokeGoal(point=[x, y, 0.04], normal=[0, 0, 1],
                                                 force_limit=3.0, depth_limit=0.008,
                                                 speed=0.005, standoff=0.005))
                handle = planner.wait_future(client.send_goal_async(goal), 20, 'goal')
                planner.wait_future(handle.get_result_async(), 60, 'poke')
                pokes += 1
            elapsed = time.monotonic() - start
            streamed = poke_node.samples_streamed - first
    finally:
        emulator.stop()
    gaps, recorded, dropped, span = [], 0, 0, 0.0
    for record in PokeStore(work / 'pokes'):
        dt = np.diff(record.t_controller)
        recorded += len(record)
        span += float(record.t_controller[-1] - record.t_controller[0])
        dropped += int(np.sum(np.maximum(np.round(dt / 0.004) - 1, 0)))
        gaps.append(dt.max())
    out.update(campaign_s=elapsed, campaign_pokes=pokes,
               ft_stream_rate_hz=streamed / elapsed,
               ft_poke_rate_hz=(recorded - pokes) / span if span else float('nan'),
               ft_rate_over_target=((recorded - pokes) / span / 250) if span else float('nan'),
               ft_samples_recorded=recorded, ft_dropped_samples=dropped,
               ft_dropped_fraction=dropped / max(recorded + dropped, 1),
               ft_max_gap_ms=1e3 * float(max(gaps)) if gaps else float('nan'))
    return out
