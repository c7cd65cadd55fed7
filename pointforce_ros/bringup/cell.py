"""``pointforce cell``: the whole node suite on the simulated cell (or on a real UR and camera).

Simulated (default): the RTDE controller emulator runs as its own process with the object's
contact physics and the scenario's sensor effects; ``sim_camera`` renders the object; the five
product nodes (``cloud_capture``, ``poke_server``, ``stiffness_learner``, ``contact_wrench``,
``deformation_force``) run in this process, each on its own supervised executor (a callback
that raises is logged and the node keeps serving; a slow one cannot starve the others).
Real: ``--robot-ip`` points ``poke_server`` at a UR controller and ``--camera-topic`` points
``cloud_capture`` at a camera driver (``deformation_force`` reads the same camera); nothing is
simulated.

Supervision (:meth:`CellSession.supervise`, every 0.5 s in ``pointforce cell``): an emulator that
exits is restarted (up to ``EMULATOR_RESTARTS`` times, the poke server pointed at the new one);
after that the cell degrades with a clear message and keeps serving capture, learning and contact
queries while pokes abort. SIGTERM, SIGHUP and Ctrl-C stop the nodes and the emulator: no
process is left holding the controller ports.

:class:`CellSession` is also the demo's and the benchmarks' way to drive the cell: capture the
surface, poke, ask for suggestions and query wrenches, all through the ROS interfaces.
"""

import os
import signal
import time
from pathlib import Path
from typing import Optional

import numpy as np

from pointforce_ros.errors import DeviceFault, InvalidInput, PointforceError
from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.bringup.sim_camera import SimCameraNode
from pointforce_ros.nodes.cloud_capture import CloudCaptureNode
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.deformation_force import DeformationForceNode
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.stiffness_learner import LATCHED, StiffnessLearnerNode
from pointforce_ros.shapes import box
from pointforce_ros.sim.objects import load_object
from pointforce_ros.sim.rtde.process import start_emulator
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.types import Mesh

SIM_OBJECT_HALFSPACE = 'halfspace'
EMULATOR_RESTARTS = 3
"""Times a dead emulator is restarted before the cell degrades to running without it."""


class CellSession:
    """Start the cell's processes and nodes; drive them through their ROS interfaces.

    Args:
        out: output directory (poke store, models, surface, logs).
        object_name: simulated object (``config/objects``), or ``halfspace`` for the analytic
            stand-in; ignored on a real cell.
        scenario: simulated sensor effects (``config/scenarios``).
        robot_ip: a real UR controller; ``None`` starts the emulator.
        camera_topic: a real PointCloud2 topic; ``None`` starts ``sim_camera``.
        shape_constant: ``c`` of the shape function used by the learner, metres.
        params_file: a ROS parameter file for the five nodes (``config/nodes.yaml``); the
            cell's own settings (paths under ``out``, the robot and camera, the simulated
            object's ROI, ``shape_constant``) win over it; on a real camera the file's ROI holds.

    """

    def __init__(self, out='out/cell', *, object_name: str = 'lamb', scenario: str = 'realistic',
                 robot_ip: Optional[str] = None, camera_topic: Optional[str] = None,
                 shape_constant: float = 0.004, views: int = 2, log=print,
                 params_file: Optional[str] = None):
        """Start everything; raises DeviceFault if the emulator or the arm cannot start."""
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        from rclpy.exceptions import NameValidationException, ParameterException
        from rclpy.node import Node
        from rclpy.parameter import Parameter

        self.out = Path(out)
        self.log = log
        self.object_name = object_name
        self.emulator = None
        self.spec = None
        self.launcher = None
        self.client_launcher = None
        self._emulator_args = None
        self.emulator_restarts = 0
        self.degraded = ''
        self._faults_seen = 0
        try:
            if robot_ip is None or camera_topic is None:
                self.spec = _load_sim_object(object_name)
            if robot_ip is None:
                kwargs = {'scenario': scenario}
                if object_name == SIM_OBJECT_HALFSPACE:
                    kwargs['halfspace'] = {'z0': 0.04}
                else:
                    kwargs['object_name'] = object_name
                centre = self.spec.centre
                log(f'[cell] starting the RTDE controller emulator ({object_name}, {scenario})')
                self._emulator_args = dict(
                    force_model='pointforce_ros.sim.scenario:make_force_model',
                    force_model_kwargs=kwargs, ready_timeout=60.0,
                    initial_pose=[centre[0], centre[1], centre[2] + 0.08, np.pi, 0.0, 0.0])
                self.emulator = start_emulator(self.out / 'logs', **self._emulator_args)
                robot_ip = self.emulator.host
                log(f'[cell] emulator ready on {robot_ip}')
            self.robot_ip = robot_ip
            self.launcher = InProcessLauncher(
                args=['--ros-args', '--params-file', str(params_file)] if params_file else None)
            ctx = self.launcher.context
            paths = {'store': self.out / 'pokes', 'models': self.out / 'models',
                     'surface': self.out / 'surface.npz',
                     'deformation': self.out / 'deformation'}
            self.paths = paths
            if camera_topic is None:
                mesh, rgb = self.spec.mesh, self.spec.rgb
                self.camera = self.launcher.add(SimCameraNode(
                    mesh, rgb, self.spec.centre,
                    camera_kwargs=load_scenario(scenario).camera_kwargs(),
                    context=ctx, parameter_overrides=[Parameter('views', value=int(views))]))
                camera_topic = '/camera/camera/depth/color/points'
            else:
                self.camera = None
            roi = self.spec.roi if self.spec is not None else [0.3, -0.2, 0.005, 0.7, 0.2, 0.3]
            capture = [Parameter('cloud_topic', value=camera_topic),
                       Parameter('surface_file', value=str(paths['surface']))]
            if self.spec is not None or not params_file:   # a real camera: the file's ROI
                capture.append(Parameter('roi', value=[float(v) for v in roi]))
            self.capture_node = self.launcher.add(CloudCaptureNode(
                context=ctx, parameter_overrides=capture), isolated=True)
            self.poke_node = self.launcher.add(PokeServerNode(context=ctx, parameter_overrides=[
                Parameter('robot_ip', value=robot_ip),
                Parameter('store_dir', value=str(paths['store']))]), isolated=True)
            self.learner_node = self.launcher.add(StiffnessLearnerNode(
                context=ctx, parameter_overrides=[
                    Parameter('store_dir', value=str(paths['store'])),
                    Parameter('model_dir', value=str(paths['models'])),
                    Parameter('shape_constant', value=float(shape_constant))]), isolated=True)
            self.wrench_node = self.launcher.add(ContactWrenchNode(context=ctx), isolated=True)
            self.deformation_node = self.launcher.add(DeformationForceNode(
                context=ctx, parameter_overrides=[
                    Parameter('model_dir', value=str(paths['deformation'])),
                    Parameter('cloud_topic', value=camera_topic)]), isolated=True)
            # the driver's clients get their own context and executor, like a separate process:
            # clients sharing a busy server's executor can lose futures (rclpy 7.1.6)
            self.client_launcher = InProcessLauncher(threads=4)
            self.client = self.client_launcher.add(Node('cell_driver',
                                                        context=self.client_launcher.context))
            self._clients()
        except (ParameterException, NameValidationException) as exc:
            self.close()     # a value of the parameter file a node refuses: out of range, ...
            raise InvalidInput(f'a node of the cell refused its parameters: {exc}') from exc
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ plumbing
    def _clients(self):
        from pointforce_interfaces.action import Poke
        from pointforce_interfaces.msg import ModelStatus
        from pointforce_interfaces.srv import (ContactWrench, ContactWrenchBatch, EstimateForce,
                                               IdentifyDeformation, SuggestPoke)
        from rclpy.action import ActionClient
        from std_srvs.srv import Trigger

        c = self.client
        self.models = []
        c.create_subscription(ModelStatus, '/stiffness_learner/model', self.models.append,
                              LATCHED)
        self.poke_client = ActionClient(c, Poke, '/poke_server/poke')
        self.suggest_client = c.create_client(SuggestPoke, '/stiffness_learner/suggest_poke')
        self.wrench_client = c.create_client(ContactWrench, '/contact_wrench/contact_wrench')
        self.batch_client = c.create_client(ContactWrenchBatch,
                                            '/contact_wrench/contact_wrench_batch')
        self.estimate_client = c.create_client(EstimateForce,
                                               '/deformation_force/estimate_force')
        self.identify_client = c.create_client(IdentifyDeformation,
                                               '/deformation_force/identify')
        self.triggers = {name: c.create_client(Trigger, f'/cloud_capture/{name}')
                         for name in ('add_scan', 'capture', 'clear')}
        if self.camera is not None:
            self.triggers['next_view'] = c.create_client(Trigger, '/sim_camera/next_view')
        for name, client in [('poke', self.poke_client)]:
            if not client.wait_for_server(timeout_sec=20.0):
                raise DeviceFault(f'action /poke_server/{name} did not appear within 20 s')
        for client in [self.suggest_client, self.wrench_client, self.batch_client,
                       self.estimate_client, self.identify_client, *self.triggers.values()]:
            if not client.wait_for_service(timeout_sec=20.0):
                raise DeviceFault(f'service {client.srv_name} did not appear within 20 s')

    def call(self, client, request, timeout: float = 60.0, what: str = 'service'):
        """Call a service and wait for its response (RuntimeError naming it on time-out)."""
        return self.client_launcher.wait_future(client.call_async(request), timeout, what)

    def set_parameter(self, node: str, name: str, value) -> None:
        """Set a parameter of a cell node over ``/<node>/set_parameters`` (``ros2 param set``).

        Raises:
            DeviceFault: the service did not appear or the node refused the value (its reason).

        """
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        client = self.client.create_client(SetParameters, f'/{node}/set_parameters')
        try:
            if not client.wait_for_service(timeout_sec=20.0):
                raise DeviceFault(f'service /{node}/set_parameters did not appear within 20 s')
            request = SetParameters.Request(
                parameters=[Parameter(name, value=value).to_parameter_msg()])
            result = self.call(client, request, 60.0, f'{node} set_parameters').results[0]
        finally:
            self.client.destroy_client(client)
        if not result.successful:
            raise DeviceFault(f'{node} refused {name} = {value}: {result.reason}')

    def trigger(self, name: str):
        """Call a std_srvs/Trigger of the cell (``add_scan``, ``capture``, ``next_view`` ...)."""
        from std_srvs.srv import Trigger
        return self.call(self.triggers[name], Trigger.Request(), 60.0, name)

    # ------------------------------------------------------------------ the job's steps
    def capture_surface(self, views: int = 2):
        """Scan from ``views`` camera viewpoints, merge, publish; returns the core Surface."""
        for view in range(views):
            if view > 0 and 'next_view' in self.triggers:
                self.trigger('next_view')
            stamp = time.monotonic()
            self.launcher.wait_for(lambda: self.capture_node._latest is not None, 10, 'a cloud')
            time.sleep(0.6)  # a frame of the new view (the camera renders at 2 Hz)
            result = self.trigger('add_scan')
            if not result.success:
                raise PointforceError(f'add_scan: {result.message}')
            self.log(f'[cell] scan {view + 1}/{views} added ({time.monotonic() - stamp:.1f} s)')
        result = self.trigger('capture')
        if not result.success:
            raise PointforceError(f'capture: {result.message}')
        self.log(f'[cell] {result.message}')
        self.launcher.wait_for(lambda: self.poke_node.surface is not None, 10,
                               'surface at the poke server')
        return self.capture_node.surface

    def poke(self, goal, timeout: float = 120.0, feedback=None):
        """Send a Poke goal (message); returns the result message (raises if rejected)."""
        handle = self.client_launcher.wait_future(
            self.poke_client.send_goal_async(goal, feedback_callback=feedback), 20, 'goal')
        if not handle.accepted:
            raise PointforceError('poke goal rejected by the server (see its log)')
        return self.client_launcher.wait_future(handle.get_result_async(), timeout, 'poke').result

    def suggest(self, count: int = 1):
        """Ask the learner for the next poke locations; returns the response."""
        from pointforce_interfaces.srv import SuggestPoke
        return self.call(self.suggest_client, SuggestPoke.Request(count=count), 60, 'suggest')

    def wait_learned(self, poke_id: str, timeout: float = 60.0):
        """Wait until the learner has used or skipped ``poke_id``; return (status, skip reason).

        ``status`` is the newest ModelStatus once the contact service runs on it, or ``None``
        when the poke was skipped (``reason`` then says why).
        """
        learner = self.launcher.wait_for(lambda: self.learner_node.learner, timeout, 'learner')
        self.launcher.wait_for(lambda: learner.processed(poke_id), timeout,
                               f'the learner to process {poke_id}')
        if poke_id in learner.skipped:
            return None, learner.skipped[poke_id]
        return self.wait_model(len(learner.curves), timeout), ''

    def wait_model(self, version: int, timeout: float = 60.0):
        """Wait until the learner has published model ``version`` (or newer); return it."""
        self.launcher.wait_for(lambda: self.models and self.models[-1].version >= version,
                               timeout, f'model v{version}')
        self.launcher.wait_for(lambda: self.wrench_node.server.version >= version, timeout,
                               f'contact service on model v{version}')
        return self.models[-1]

    # ------------------------------------------------------------------ supervision
    def supervise(self):
        """Check the cell's parts once; return what changed, one line each (empty if nothing).

        A callback fault recorded by an executor is reported (the node keeps serving). A dead
        emulator is restarted and ``poke_server`` pointed at it, at most ``EMULATOR_RESTARTS``
        times; then the cell runs degraded (:attr:`degraded` says why) without it.
        """
        lines = []
        faults = self.launcher.faults if self.launcher is not None else []
        for _, where, exc in faults[self._faults_seen:]:
            lines.append(f'[cell] {where}: a callback raised {type(exc).__name__}: {exc}; '
                         'the node keeps serving')
        self._faults_seen = len(faults)
        if self.emulator is None or self.emulator.alive() or self.degraded:
            return lines
        code = self.emulator.process.returncode
        tail = self.emulator.log()[-600:].strip()
        self.emulator.stop()
        if self.emulator_restarts >= EMULATOR_RESTARTS:
            self.degraded = (f'the RTDE controller emulator exited (code {code}) after '
                             f'{self.emulator_restarts} restarts; the cell keeps serving '
                             'capture, learning and contact queries, pokes abort')
            return lines + [f'[cell] DEGRADED: {self.degraded}. Its log ends:\n{tail}']
        self.emulator_restarts += 1
        lines.append(f'[cell] the emulator on {self.emulator.host} exited (code {code}); '
                     f'restarting it ({self.emulator_restarts}/{EMULATOR_RESTARTS})')
        try:
            self.emulator = start_emulator(self.out / 'logs', **self._emulator_args)
        except DeviceFault as exc:
            self.degraded = f'the RTDE controller emulator could not be restarted: {exc}'
            return lines + [f'[cell] DEGRADED: {self.degraded}']
        self.robot_ip = self.emulator.host
        self.poke_node.robot_ip = self.emulator.host   # the next goal reconnects there
        return lines + [f'[cell] emulator back on {self.emulator.host}']

    def close(self):
        """Stop the nodes and the emulator."""
        if self.client_launcher is not None:
            self.client_launcher.close()
            self.client_launcher = None
        if self.launcher is not None:
            self.launcher.close()
            self.launcher = None
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _SimObject:
    """What the cell needs of a simulated object: rendering mesh, colours, centre, ROI."""

    def __init__(self, mesh, rgb, centre, roi, spec=None, force_cap=8.0, max_depth=0.01):
        self.mesh, self.rgb, self.centre, self.roi = mesh, rgb, np.asarray(centre), roi
        self.spec, self.force_cap, self.max_depth = spec, force_cap, max_depth


def _load_sim_object(name: str) -> _SimObject:
    if name == SIM_OBJECT_HALFSPACE:
        b = box((0.08, 0.06, 0.04))
        mesh = Mesh(vertices=b.vertices + [0.5, 0.0, 0.0], triangles=b.triangles)
        rgb = np.tile([0.7, 0.5, 0.4], (len(mesh.vertices), 1))
        return _SimObject(mesh, rgb, [0.5, 0.0, 0.04], [0.44, -0.05, 0.01, 0.56, 0.05, 0.1],
                          force_cap=5.0, max_depth=0.012)
    spec = load_object(name)
    mesh, rgb = spec.surface_mesh()
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
    roi = [lo[0] - 0.01, lo[1] - 0.01, 0.005, hi[0] + 0.01, hi[1] + 0.01, hi[2] + 0.03]
    return _SimObject(mesh, rgb, centre, roi, spec=spec, force_cap=float(spec.force_cap),
                      max_depth=float(spec.max_depth))


_STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP, signal.SIGINT)


def _raise_interrupt(signum, frame):
    """Stop the cell on the first signal; later ones are ignored so the clean-up completes."""
    for sig in _STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    raise KeyboardInterrupt(signal.Signals(signum).name)


def run_cell(out='out/cell', object_name='lamb', scenario='realistic', robot_ip=None,
             camera_topic=None, duration: Optional[float] = None,
             params_file: Optional[str] = None) -> int:
    """CLI body of ``pointforce cell``: start everything and serve until Ctrl-C or SIGTERM.

    SIGTERM, SIGHUP and Ctrl-C stop the cell (nodes, then the emulator), also during start-up;
    a second signal during the clean-up is ignored. Every 0.5 s the cell supervises its parts
    (:meth:`CellSession.supervise`).
    """
    previous = {sig: signal.signal(sig, _raise_interrupt) for sig in _STOP_SIGNALS}
    try:
        with CellSession(out, object_name=object_name, scenario=scenario, robot_ip=robot_ip,
                         camera_topic=camera_topic, params_file=params_file) as cell:
            print(f'[cell] running: poke action /poke_server/poke on {cell.robot_ip}, '
                  'services /contact_wrench/contact_wrench(_batch), '
                  '/stiffness_learner/suggest_poke, /cloud_capture/{add_scan,capture}, '
                  '/deformation_force/{identify,estimate_force}. '
                  'Ctrl-C to stop.', flush=True)
            start = time.monotonic()
            while duration is None or time.monotonic() - start < duration:
                time.sleep(0.5)
                for line in cell.supervise():
                    print(line, flush=True)
    except KeyboardInterrupt as stop:
        print(f'[cell] stopping ({stop or "Ctrl-C"})', flush=True)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
