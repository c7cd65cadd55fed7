"""``pointforce demo``: start the contact service in-process and answer planner queries over DDS.

Foundation version: the model is a analytic heterogeneous patch (a Hertz-like point law whose
stiffness doubles over an inclusion) so that the service has something to answer before the
simulated cell exists; the answer is checked against the same solver called without ROS.
"""

import os
import time
from pathlib import Path

import numpy as np

from pointforce_ros.model_io import ContactModel, save_model
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface


def analytic_patch_model(spacing: float = 0.002, version: int = 1) -> ContactModel:
    """Flat 80 x 60 mm patch at z = 0.04 m, f = k(x) d^1.5 with a stiff disc at the centre."""
    xs = np.arange(0.46, 0.54 + 1e-9, spacing)
    ys = np.arange(-0.03, 0.03 + 1e-9, spacing)
    gx, gy = np.meshgrid(xs, ys, indexing='ij')
    points = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.04)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    r = np.hypot(points[:, 0] - 0.5, points[:, 1])
    k = 4.0e3 * (1.0 + 1.0 / (1.0 + np.exp((r - 0.012) / 0.002)))  # N / m^1.5
    colors = np.stack([0.8 - 0.3 * (k > 6e3), 0.5 * np.ones_like(k), 0.4 * np.ones_like(k)], 1)
    depths = np.linspace(0.0, 0.02, 41)
    forces = k[:, None] * depths[None, :] ** 1.5
    slopes = 1.5 * k * depths[-1] ** 0.5
    baked = BakedResponse(depths=depths, forces=forces, slopes=slopes, version=version,
                          meta={'kind': 'analytic', 'law': 'k d^1.5'})
    return ContactModel(surface=Surface(points=points, normals=normals, colors=colors),
                        response=baked, shape_constant=0.004, version=version,
                        meta={'source': 'pointforce demo analytic patch'})


def run_demo(out: str = 'out/demo', quick: bool = False) -> int:
    """Run the demo; returns a process exit code."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    from geometry_msgs.msg import Vector3
    from pointforce_interfaces.srv import ContactWrench
    from rclpy.node import Node

    from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
    from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
    from pointforce_ros.nodes.launcher import InProcessLauncher
    from pointforce_ros.serving import WrenchServer
    from pointforce_ros.shapes import icosphere
    from pointforce_ros.types import ContactQuery, Pose
    from rclpy.parameter import Parameter

    out_dir = Path(out)
    model_dir = out_dir / 'models'
    model = analytic_patch_model()
    path = save_model(model, model_dir)
    print(f'[demo] model v{model.version} with {len(model.surface)} surface points -> {path}')
    sphere = icosphere(0.02, 2)
    pose = Pose(position=[0.5, 0.0, 0.04 + 0.02 - 0.003])  # sphere 3 mm into the surface
    approach = np.array([0.0, 0.0, -1.0])
    centre = pose.position
    with InProcessLauncher() as launcher:
        started = time.monotonic()
        launcher.add(ContactWrenchNode(
            context=launcher.context,
            parameter_overrides=[Parameter('model_dir', value=str(model_dir))]))
        client_node = launcher.add(Node('demo_planner', context=launcher.context))
        client = client_node.create_client(ContactWrench, '/contact_wrench/contact_wrench')
        if not client.wait_for_service(timeout_sec=20.0):
            raise RuntimeError('service /contact_wrench/contact_wrench did not appear in 20 s')
        request = ContactWrench.Request(mesh=mesh_to_msg(sphere), pose=pose_to_msg(pose),
                                        approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                        torque_centre=to_point(centre),
                                        return_displacements=True)
        sent = time.monotonic()
        response = launcher.wait_future(client.call_async(request), 20.0, 'contact_wrench')
        rtt = time.monotonic() - sent
        print(f'[demo] service up in {sent - started:.2f} s; answer in {1e3 * rtt:.1f} ms')
    if not response.success:
        print(f'[demo] service refused: {response.message}')
        return 1
    f, m = response.wrench.force, response.wrench.torque
    print(f'[demo] sphere r=20 mm, 3 mm into the stiff centre, approach -z (model '
          f'v{response.model_version}):')
    print(f'[demo]   force  = ({f.x:+.3f}, {f.y:+.3f}, {f.z:+.3f}) N')
    print(f'[demo]   torque = ({m.x:+.5f}, {m.y:+.5f}, {m.z:+.5f}) N m about the sphere centre')
    print(f'[demo]   contact points = {response.contact_count}, max surface displacement = '
          f'{1e3 * response.max_displacement:.2f} mm, displaced points returned = '
          f'{len(response.displacements)}')
    server = WrenchServer()
    server.swap(model)
    direct = server.answer(ContactQuery(mesh=sphere, poses=(pose,), approach=approach,
                                        torque_centre=centre))[0]
    diff = np.abs(direct.wrench.force - np.array([f.x, f.y, f.z])).max()
    print(f'[demo] same query without ROS: Fz = {direct.wrench.force[2]:+.3f} N '
          f'(|difference| {diff:.2e} N)')
    return 0 if diff < 1e-9 else 1
