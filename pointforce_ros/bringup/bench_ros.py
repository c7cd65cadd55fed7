"""``pointforce bench ros``: what ROS costs on top of the core, and the live F/T stream quality.

Figures, each against a baseline measured in the same run:

* single ContactWrench round trip over Fast DDS (p50, p99), the mesh sent in the request's flat
  form, against the same query called on the core directly (``ros_rtt_over_core``,
  ``ros_overhead_p50_ms``: round trip minus core), the same request with the mesh as a
  ``shape_msgs/Mesh`` (``single_rtt_mesh_msg_*``: rclpy builds a Python object per vertex and
  triangle on both sides) and a trivial ``std_srvs/Trigger`` service's round trip (what rclpy
  and DDS cost for nothing);
* where the ``DirectClient`` series' time goes in the service, from the contact node's own
  ``~/service_timing`` report (``service_take_p50_ms``: taking the request from the
  middleware, ``service_callback_p50_ms``, ``service_send_p50_ms``: sending the response); the
  rest of the round trip is the middleware's delivery and the two wake-ups;
* small batches (``small_batch`` poses, p50 and p99) against the core's batch call, and the
  throughput of one large batch over ROS (poses/s) against the core (``batch_ros_over_core``);

Single-query series are timed in bursts (``BURST`` calls back to back, as a planner scoring
candidates sends them; the series' bursts alternate so all see the same load), and once more
with the service idle for ``IDLE_S`` before each call (``single_rtt_after_idle_*``: a
planner's occasional query; on this VM an idle virtual CPU takes up to a millisecond to come
back).
Round trips are timed by an event-driven client: the future's done callback sets a
``threading.Event`` the benchmark waits on (with a deadline), so no poll period is in the figure.
The client spins on a ``SingleThreadedExecutor`` (as ``spin_until_future_complete`` does); the
``*_mt_client`` series repeat the single query and the Trigger from a client on a 2-thread
``MultiThreadedExecutor``, whose hand-off to its pool costs about 0.4 ms per round trip here.
The contact service runs as deployed, in its own process (``python -m
pointforce_ros.nodes.contact_wrench``, the console script's ``main``), and so does the Trigger
service (on the same kind of executor); the benchmark is the planner's process. All of them use
a ROS domain of their own.
* load (issue 16): ``load_clients`` client processes (8) each send ``load_calls`` (500) single
  queries back to back, started together; failures and p50/p99 over every call, and the CPU
  each call costs the service and the clients. Four times: every client on the one service
  name (``load_*``); each client on a lane of its own (``load_lanes_*``: the node's
  ``client_lanes`` services); the same through :class:`DirectClient` (``load_direct_*``);
  and that with a second worker process of the service, half the clients on each
  (``load_procs_*``: ``contact_wrench_1``, the same node under another name). Every client of
  a service receives every reply and discards those to other clients' calls (rmw_fastrtps and
  rmw_cyclonedds alike, ros2/rclcpp#2397); in rclpy each such reply wakes the client's
  executor, so on the shared name one call costs every other client CPU too
  (``load_client_cpu_per_call_ms``).
* the F/T stream of a poke campaign through the real ur_rtde against the emulator: the rate inside
  the recorded pokes against the 250 Hz target (``ft_rate_over_target``), the rate over the whole
  campaign including the time between pokes, and dropped samples (controller-time gaps).
"""

import contextlib
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Tuple

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3
import numpy as np
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
import rclpy
from rclpy.action import ActionClient
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rcl_interfaces.srv import SetParameters
from std_srvs.srv import Trigger

from msg_adapters.geometry import mesh_to_flat, mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup.domain import private_domain
from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.nodes.contact_wrench import (HOT_WAIT_MS, REQUESTS, spin_single_threaded,
                                                 TIMING_PERIOD)
from pointforce_ros.nodes.direct_client import DirectClient, ServiceTimeout
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.service_loop import ServiceLoop, STAGES, TIMING_WINDOW
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.shapes import icosphere
from pointforce_ros.sim.rtde.process import start_emulator
from pointforce_ros.types import ContactQuery, PokeGoal, Pose

CENTRE = np.array([0.5, 0.0, 0.06])
WORKER_NODES = ('contact_wrench', 'contact_wrench_1')
"""Node names of the contact service's worker processes (the first serves every series)."""
SPHERE_RADIUS, SPHERE_LEVEL = 0.02, 2
BURST = 25
"""Single queries each latency series sends back to back before the next series' turn."""
IDLE_S = 0.01
"""Idle time before each call of the ``single_rtt_after_idle`` series, seconds."""

WARM_UP_TRIES = 5
"""Attempts of each warm-up call: a service's first reply to a new client can be lost while
discovery is incomplete (Fast DDS drops it: "failed to send response (timeout)"; one full
bench run here lost its first Trigger reply and waited out 30 s)."""

WARM_UP_TIMEOUT = 2.0
"""Seconds one warm-up attempt waits for its reply."""


def _percentiles(values):
    values = np.asarray(values) * 1e3
    return float(np.percentile(values, 50)), float(np.percentile(values, 99))


def round_trip(client, request, timeout: float, what: str):
    """Call ``client`` once; return (seconds from the call to the response, response).

    Event-driven: the future's done callback (run by the client's executor) sets an Event.

    Raises:
        RuntimeError: no response within ``timeout`` seconds.

    """
    done = threading.Event()
    start = time.perf_counter()
    future = client.call_async(request)
    future.add_done_callback(lambda _future: done.set())
    if not done.wait(timeout):
        client.remove_pending_request(future)
        raise RuntimeError(f'timed out after {timeout:.1f} s waiting for {what}')
    elapsed = time.perf_counter() - start
    return elapsed, future.result()


def warm_up_call(client, request, what: str, tries: int = WARM_UP_TRIES,
                 timeout: float = WARM_UP_TIMEOUT):
    """Call ``client`` (an rclpy client or a :class:`DirectClient`) until one reply arrives.

    Returns the response. A lost reply (discovery not complete) is asked again, up to
    ``tries`` attempts of ``timeout`` seconds each.

    Raises:
        RuntimeError: no reply to any attempt.

    """
    for _ in range(tries):
        try:
            if isinstance(client, DirectClient):
                return client.call(request, timeout)
            return round_trip(client, request, timeout, what)[1]
        except (RuntimeError, ServiceTimeout):
            continue
    raise RuntimeError(f'no reply from {what} to {tries} warm-up calls of {timeout:g} s')


class _TriggerNode(Node):
    """Trivial std_srvs/Trigger services, the round trip's baselines.

    ``~/trigger`` and ``~/trigger_mt`` on the node's executor (what rclpy's stock path costs
    for nothing), ``~/trigger_direct`` on a :class:`ServiceLoop` (the floor of the path the
    contact service takes).
    """

    def __init__(self, context=None):
        super().__init__('bench_trigger', context=context)
        group = ReentrantCallbackGroup()
        self.create_service(Trigger, '~/trigger', _answer_trigger, callback_group=group)
        # the multi-threaded client's own name: a client's executor wakes for every reply of
        # its service, its own or another client's (see load_client), so two series on one
        # name would each pay for the other's replies
        self.create_service(Trigger, '~/trigger_mt', _answer_trigger, callback_group=group)
        self._loop = ServiceLoop(self)
        self._loop.add(Trigger, '~/trigger_direct', _answer_trigger, REQUESTS)
        self._loop.start()

    def destroy_node(self):
        self._loop.stop()
        return super().destroy_node()


def _answer_trigger(request, response):
    response.success = True
    return response


def _trigger_node(context=None):
    """Return the node of the trivial Trigger services (:class:`_TriggerNode`)."""
    return _TriggerNode(context=context)


def _bench_poses(n: int, seed: int = 0):
    """``n`` poses of the benchmark's sphere over the patch, 0-4 mm deep (seeded)."""
    rng = np.random.default_rng(seed)
    return [Pose(position=[0.5 + dx, dy, 0.06 - d]) for dx, dy, d in
            zip(rng.uniform(-0.02, 0.02, n), rng.uniform(-0.015, 0.015, n),
                rng.uniform(0.0, 0.004, n))]


def _single_request(pose, mesh_fields, skip_uncertainty: bool = True):
    """Build a single query; the latency series skip the wrench's spread (four more solves)."""
    return ContactWrench.Request(pose=pose_to_msg(pose), approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                 torque_centre=to_point(CENTRE), skip_uncertainty=skip_uncertainty,
                                 **mesh_fields)


def _start(*args) -> subprocess.Popen:
    """Start ``python -m <args>`` in its own process (stdin/stdout piped, stderr inherited)."""
    return subprocess.Popen([sys.executable, '-m', *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)


def _stop(processes) -> None:
    for proc in processes:
        if proc.poll() is None:
            proc.terminate()
    for proc in processes:
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def load_client(calls: int, seed: int, service: str = '/contact_wrench/contact_wrench',
                direct: bool = False) -> None:
    """One load-test client process: ``calls`` single queries to ``service`` after ``go``.

    ``direct``: call through :class:`DirectClient` (no executor), else through rclpy's client
    spun by a ``SingleThreadedExecutor`` thread, the done callback setting an Event.
    Prints ``ready`` once the service is found, waits for a line on stdin, then prints one JSON
    line: round-trip seconds of the answered calls, the failures and the CPU seconds the whole
    process (every thread) used during the calls.
    """
    rclpy.init()
    node = Node(f'bench_load_{seed}')
    if direct:
        direct_client = DirectClient(node, ContactWrench, service, REQUESTS)
        if not direct_client.wait_for_service(timeout_sec=60):
            raise RuntimeError(f'service {service} did not appear in 60 s')

        def call(request):
            start = time.perf_counter()
            try:
                response = direct_client.call(request, 30)
            except ServiceTimeout as exc:
                raise RuntimeError(str(exc)) from None
            return time.perf_counter() - start, response
    else:
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        threading.Thread(target=executor.spin, daemon=True).start()
        # a reply reader sees the replies to every client: at the default depth of 10 a busy
        # client's own reply can be pushed out of its history by the others'
        client = node.create_client(ContactWrench, service, qos_profile=REQUESTS)
        if not client.wait_for_service(timeout_sec=60):
            raise RuntimeError(f'service {service} did not appear in 60 s')

        def call(request):
            return round_trip(client, request, 30, 'contact_wrench')
    vertices, triangles = mesh_to_flat(icosphere(SPHERE_RADIUS, SPHERE_LEVEL))
    flat = dict(mesh_vertices=vertices, mesh_triangles=triangles)
    requests = [_single_request(p, flat) for p in _bench_poses(calls, seed=1000 + seed)]
    call(requests[0])   # discovery of the reply path
    print('ready', flush=True)
    sys.stdin.readline()
    cpu_start = time.process_time()
    times, failures = [], []
    for request in requests:
        try:
            elapsed, response = call(request)
        except RuntimeError as exc:
            failures.append(str(exc))
            continue
        if response.success:
            times.append(elapsed)
        else:
            failures.append(response.message)
    print(json.dumps(dict(times=times, failures=failures,
                          cpu_s=time.process_time() - cpu_start)), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    os._exit(0)   # the spinning daemon thread would abort the interpreter's exit


def _peak_rss_mb(pid: int) -> float:
    """Peak resident memory of process ``pid`` (``VmHWM``), MiB; NaN where /proc has none."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float('nan')


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds process ``pid`` has used (``/proc``); NaN where it has none."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return float('nan')


def _load_test(clients: int, calls: int, service_pids, lanes: bool = False,
               direct: bool = False, nodes=('contact_wrench',)) -> dict:
    """``clients`` processes x ``calls`` single queries, started together.

    ``lanes``: client ``i`` calls ``/<node>/lane_<i>/contact_wrench`` (the service's
    ``client_lanes``), else every client calls ``/contact_wrench/contact_wrench``. ``direct``:
    the clients call through :class:`DirectClient`. ``nodes``: the contact service processes'
    node names, client ``i`` on ``nodes[i % len(nodes)]`` (worker processes; their
    ``service_pids`` are summed for the service's CPU). Keys are prefixed ``load_``,
    ``load_lanes_``, ``load_direct_`` (lanes and direct clients) or ``load_procs_`` (lanes,
    direct clients and more than one service process).
    """
    prefix = ('load_procs_' if len(nodes) > 1 else 'load_direct_' if direct
              else 'load_lanes_' if lanes else 'load_')
    procs = [_start('pointforce_ros.bringup.bench_ros', 'client', str(calls), str(i),
                    f'/{nodes[i % len(nodes)]}/lane_{i}/contact_wrench' if lanes
                    else '/contact_wrench/contact_wrench', *(['direct'] if direct else []))
             for i in range(clients)]
    try:
        for proc in procs:
            line = proc.stdout.readline()
            if line.strip() != 'ready':
                raise RuntimeError(f'load client did not start (said {line!r})')
        service_cpu = sum(_cpu_seconds(pid) for pid in service_pids)
        start = time.perf_counter()
        for proc in procs:
            proc.stdin.write('go\n')
            proc.stdin.flush()
        results = [json.loads(proc.stdout.readline()) for proc in procs]
        wall = time.perf_counter() - start
        service_cpu = sum(_cpu_seconds(pid) for pid in service_pids) - service_cpu
    finally:
        _stop(procs)
    times = [t for r in results for t in r['times']]
    p50, p99 = _percentiles(times) if times else (float('nan'), float('nan'))
    answered = max(len(times), 1)
    out = dict(clients=clients, calls_per_client=calls,
               failures=int(sum(len(r['failures']) for r in results)),
               failure_messages=sorted({m for r in results for m in r['failures']})[:5],
               rtt_p50_ms=p50, rtt_p99_ms=p99, calls_per_s=len(times) / wall,
               service_cpu_per_call_ms=1e3 * service_cpu / answered,
               client_cpu_per_call_ms=1e3 * sum(r['cpu_s'] for r in results) / answered)
    return {prefix + key: value for key, value in out.items()}


def _timing_reports(planner) -> list:
    """Subscribe the planner to the contact service's ``~/service_timing``; return the list."""
    node = planner.add(Node('bench_timing', context=planner.context))
    reports = []
    node.create_subscription(DiagnosticStatus, '/contact_wrench/service_timing', reports.append,
                             10)
    return reports


def _service_stages(planner, reports: list, n_single: int) -> dict:
    """Return the service's own account of the ``DirectClient`` series (lane 1), p50 in ms.

    Read from the contact node's ``~/service_timing`` report that includes the series (within
    two report periods): taking the request, the callback, sending the response, over the
    lane's latest answers (warm-up, bursts and the calls after idle; at most
    :data:`~pointforce_ros.nodes.service_loop.TIMING_WINDOW`).
    """
    lane = '/contact_wrench/lane_1/contact_wrench'

    def latest():
        for report in reversed(reports):
            values = {kv.key: kv.value for kv in report.values}
            if float(values.get(f'{lane} answers', 0)) >= min(n_single, TIMING_WINDOW):
                return values
        return None
    values = planner.wait_for(latest, 2 * TIMING_PERIOD + 5, 'the service timing report',
                              period=0.1)
    return {f'service_{stage}_p50_ms': float(values[f'{lane} {stage}_p50_ms'])
            for stage in STAGES}


def _round_trips(planner, sphere, poses, n_single, n_small, small_batch):
    """Single, Mesh-message, Trigger, small-batch and large-batch round trips (seconds).

    The planner's client node spins on a ``SingleThreadedExecutor`` of its own, as a planner
    calling ``spin_until_future_complete`` does; a second client node on the launcher's
    ``MultiThreadedExecutor`` times the single query and the Trigger again (``*_mt``), so the
    cost of the client's executor choice is in the same run. The second node calls its own
    service names (the contact service's lane 0, the Trigger node's ``~/trigger_mt``), so
    neither series receives the other's replies. A third pair of series calls through the
    package's :class:`DirectClient` (no executor; lane 1 and ``~/trigger_direct``, the latter
    served on a :class:`ServiceLoop` as the contact service is).
    """
    client_node = planner.add(Node('bench_client', context=planner.context), isolated=True,
                              threads=1)
    mt_node = planner.add(Node('bench_client_mt', context=planner.context))
    single = client_node.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    batch = client_node.create_client(ContactWrenchBatch, '/contact_wrench/contact_wrench_batch')
    trigger = client_node.create_client(Trigger, '/bench_trigger/trigger')
    single_mt = mt_node.create_client(ContactWrench, '/contact_wrench/lane_0/contact_wrench')
    trigger_mt = mt_node.create_client(Trigger, '/bench_trigger/trigger_mt')
    with _direct_clients(planner) as (single_direct, trigger_direct):
        return _timed_round_trips(single, batch, trigger, single_mt, trigger_mt, single_direct,
                                  trigger_direct, sphere, poses, n_single, n_small,
                                  small_batch)


@contextlib.contextmanager
def _direct_clients(planner):
    """Yield the package's executor-free clients (names of their own: lane 1, trigger_direct)."""
    node = Node('bench_client_direct', context=planner.context)
    clients = (DirectClient(node, ContactWrench, '/contact_wrench/lane_1/contact_wrench',
                            REQUESTS),
               DirectClient(node, Trigger, '/bench_trigger/trigger_direct', REQUESTS))
    try:
        yield clients
    finally:
        for client in clients:
            client.destroy()
        node.destroy_node()


def _direct_trip(client, request) -> Tuple[float, object]:
    """Return (seconds, response) of one blocking ``DirectClient`` call (no polling)."""
    start = time.perf_counter()
    response = client.call(request, 30)
    return time.perf_counter() - start, response


def _timed_round_trips(single, batch, trigger, single_mt, trigger_mt, single_direct,
                       trigger_direct, sphere, poses, n_single, n_small, small_batch):
    """Time the series of :func:`_round_trips` (seconds), given its clients."""
    for client in (single, batch, trigger, single_mt, trigger_mt, single_direct,
                   trigger_direct):
        if not client.wait_for_service(timeout_sec=60):
            raise RuntimeError(f'service {client.srv_name} did not appear within 60 s')
    vertices, triangles = mesh_to_flat(sphere)
    flat = dict(mesh_vertices=vertices, mesh_triangles=triangles)
    as_msg = dict(mesh=mesh_to_msg(sphere))
    approach = Vector3(x=0.0, y=0.0, z=-1.0)

    def batch_request(chosen):
        return ContactWrenchBatch.Request(poses=[pose_to_msg(p) for p in chosen],
                                          approach=approach, torque_centre=to_point(CENTRE),
                                          skip_uncertainty=True, **flat)

    for pose in poses[:20]:   # warm-up: discovery, the server's mesh cache
        for client in (single, single_mt, single_direct):
            warm_up_call(client, _single_request(pose, flat), 'contact_wrench')
        for client in (trigger, trigger_mt, trigger_direct):
            warm_up_call(client, Trigger.Request(), 'trigger')
    rtt, msg_rtt, trigger_rtt, mt_rtt, mt_trigger_rtt = [], [], [], [], []
    direct_rtt, direct_trigger_rtt, idle_rtt, std_rtt = [], [], [], []

    def contact(client, request):
        elapsed, resp = (_direct_trip(client, request) if client is single_direct
                         else round_trip(client, request, 30, 'contact_wrench'))
        if not resp.success:
            raise RuntimeError(f'contact_wrench refused: {resp.message}')
        return elapsed
    # Each series calls back to back within a block of BURST poses, as a planner scoring
    # candidates does; the blocks of the series alternate, so all see the same machine load.
    for s in range(0, n_single, BURST):
        block = poses[s:min(s + BURST, n_single)]
        for client, mesh, times in ((single, flat, rtt), (single, as_msg, msg_rtt),
                                    (single_mt, flat, mt_rtt), (single_direct, flat, direct_rtt)):
            requests = [_single_request(pose, mesh) for pose in block]
            times.extend(contact(client, request) for request in requests)
        for pose in block:    # with the wrench's standard deviation, in the same blocks
            elapsed, resp = round_trip(single, _single_request(pose, flat, False), 30,
                                       'contact_wrench')
            if not (resp.success and resp.has_wrench_std):
                raise RuntimeError(f'contact_wrench gave no wrench_std: {resp.message}')
            std_rtt.append(elapsed)
        for client, times in ((trigger, trigger_rtt), (trigger_mt, mt_trigger_rtt)):
            times.extend(round_trip(client, Trigger.Request(), 30, 'trigger')[0]
                         for _ in block)
        direct_trigger_rtt.extend(_direct_trip(trigger_direct, Trigger.Request())[0]
                                  for _ in block)
    # a planner's occasional query: the service idle for IDLE_S before each call (on a VM an
    # idle virtual CPU takes its time to come back; the sleep is outside the timed call)
    for pose in poses[:max(n_single // 5, 20)]:
        request = _single_request(pose, flat)
        time.sleep(IDLE_S)
        idle_rtt.append(contact(single_direct, request))
    small_rtt = []
    n_batch = len(poses)
    for i in range(n_small):
        request = batch_request(poses[(i * small_batch) % n_batch:][:small_batch])
        elapsed, resp = round_trip(batch, request, 60, 'contact_wrench_batch')
        if not resp.success:
            raise RuntimeError(f'batch refused: {resp.message}')
        small_rtt.append(elapsed)
    ros_batch, resp = round_trip(batch, batch_request(poses), 120, 'contact_wrench_batch')
    if not resp.success:
        raise RuntimeError(f'batch refused: {resp.message}')
    return dict(rtt=rtt, msg_rtt=msg_rtt, trigger_rtt=trigger_rtt, small_rtt=small_rtt,
                ros_batch=ros_batch, std_rtt=std_rtt, mt_rtt=mt_rtt,
                mt_trigger_rtt=mt_trigger_rtt, direct_rtt=direct_rtt,
                direct_trigger_rtt=direct_trigger_rtt, idle_rtt=idle_rtt)


def _round_trips_without_hot_wait(planner, sphere, poses, n_single):
    """Time the ``DirectClient`` single-query series again with the service's ``hot_wait`` at 0.

    Set through the node's own parameter service, then set back to :data:`HOT_WAIT_MS`: the
    same processes and machine minutes, so the pair shows what the polling window buys.
    """
    node = Node('bench_client_sleepy', context=planner.context)
    setter = DirectClient(node, SetParameters, '/contact_wrench/set_parameters')
    vertices, triangles = mesh_to_flat(sphere)
    flat = dict(mesh_vertices=vertices, mesh_triangles=triangles)

    def set_hot_wait(value):
        if not setter.wait_for_service(timeout_sec=30):
            raise RuntimeError('contact_wrench/set_parameters did not appear within 30 s')
        result = setter.call(SetParameters.Request(parameters=[
            Parameter('hot_wait', value=float(value)).to_parameter_msg()]), 30).results[0]
        if not result.successful:
            raise RuntimeError(f'hot_wait not set: {result.reason}')
    times = []
    try:
        with _direct_clients(planner) as (single, _):
            set_hot_wait(0.0)
            for pose in poses[:5]:
                warm_up_call(single, _single_request(pose, flat), 'contact_wrench')
            for pose in poses[:n_single]:
                elapsed, response = _direct_trip(single, _single_request(pose, flat))
                times.append(elapsed)
                if not response.success:
                    raise RuntimeError(f'contact_wrench refused: {response.message}')
            set_hot_wait(HOT_WAIT_MS)
    finally:
        setter.destroy()
        node.destroy_node()
    return times


def bench_ros(quick: bool = False, campaign: bool = True, load_clients: int = 8,
              load_calls: int = 500) -> dict:
    """Run the benchmark; returns a JSON-able dict (times in ms unless the key says).

    ``campaign=False`` leaves out the poke campaign (the F/T stream figures); ``quick`` uses
    fewer calls (and ``load_calls`` of 50). Everything runs in a ROS domain of its own
    (:func:`~pointforce_ros.bringup.domain.private_domain`), the poke campaign included.
    """
    with private_domain() as domain:
        out = _bench_ros(quick, campaign, load_clients, load_calls)
    out['ros_domain'] = domain
    return out


def _bench_ros(quick: bool, campaign: bool, load_clients: int, load_calls: int) -> dict:
    n_single = 100 if quick else 500
    n_small = 50 if quick else 200
    small_batch = 100
    n_batch = 1000 if quick else 10000
    load_calls = min(load_calls, 50) if quick else load_calls
    campaign_s = 10.0 if quick else 60.0
    out = {}
    work = Path(tempfile.mkdtemp(prefix='pointforce-bench-ros-'))
    base = patch_contact_model(spacing=0.002)
    # uncertainty sources as a calibration stores them: the spread costs what it costs a user
    model = dataclasses.replace(base, meta={**base.meta, 'relative_std': 0.05,
                                            'shape_cov': [[0.04, 0.0], [0.0, 100.0]]})
    save_model(model, work / 'models')
    sphere = icosphere(SPHERE_RADIUS, SPHERE_LEVEL)
    poses = _bench_poses(n_batch)
    server = WrenchServer()
    server.swap(model)

    def query(chosen):
        return ContactQuery(mesh=sphere, poses=tuple(chosen), approach=[0, 0, -1],
                            torque_centre=CENTRE)
    for pose in poses[:5]:  # warm-up: the first query builds the projection cache
        server.answer(query([pose]))
    core = []
    for pose in poses[:n_single]:
        start = time.perf_counter()
        server.answer(query([pose]))
        core.append(time.perf_counter() - start)
    core_small = []
    for i in range(n_small):
        chunk = poses[(i * small_batch) % n_batch:][:small_batch]
        start = time.perf_counter()
        server.answer_batch(query(chunk))
        core_small.append(time.perf_counter() - start)
    start = time.perf_counter()
    server.answer_batch(query(poses))
    core_batch = time.perf_counter() - start
    # the services as deployed, each in its own process; this process is the planner
    # (and a second worker process of the contact service for the last load run: the same
    # node under another name, up as long as the first)
    contact = [_start('pointforce_ros.nodes.contact_wrench', '--ros-args',
                      *(['-r', f'__node:={name}'] if name != 'contact_wrench' else []),
                      '-p', f'model_dir:={work / "models"}',
                      '-p', f'client_lanes:={max(load_clients, 2)}')
               for name in WORKER_NODES]
    services = [*contact, _start('pointforce_ros.bringup.bench_ros', 'trigger')]
    try:
        with InProcessLauncher(threads=2) as planner:
            reports = _timing_reports(planner)
            trips = _round_trips(planner, sphere, poses, n_single, n_small, small_batch)
            out.update(_service_stages(planner, reports, n_single))
            sleepy = _round_trips_without_hot_wait(planner, sphere, poses, n_single)
        pids = [contact[0].pid]
        out.update(_load_test(load_clients, load_calls, pids))
        out.update(_load_test(load_clients, load_calls, pids, lanes=True))
        out.update(_load_test(load_clients, load_calls, pids, lanes=True, direct=True))
        out.update(service_peak_rss_mb=_peak_rss_mb(contact[0].pid))
        # both worker processes, half the clients on each
        out.update(_load_test(load_clients, load_calls, [proc.pid for proc in contact],
                              lanes=True, direct=True, nodes=WORKER_NODES))
    finally:
        _stop(services)
    ros_batch = trips['ros_batch']
    p50, p99 = _percentiles(trips['rtt'])
    c50, c99 = _percentiles(core)
    t50, t99 = _percentiles(trips['trigger_rtt'])
    m50, m99 = _percentiles(trips['msg_rtt'])
    s50, s99 = _percentiles(trips['std_rtt'])
    b50, b99 = _percentiles(trips['small_rtt'])
    mt50, mt99 = _percentiles(trips['mt_rtt'])
    mtt50, mtt99 = _percentiles(trips['mt_trigger_rtt'])
    bc50, bc99 = _percentiles(core_small)
    d50, d99 = _percentiles(trips['direct_rtt'])
    n50, n99 = _percentiles(sleepy)
    dt50, dt99 = _percentiles(trips['direct_trigger_rtt'])
    i50, i99 = _percentiles(trips['idle_rtt'])
    out.update(single_rtt_p50_ms=p50, single_rtt_p99_ms=p99, core_query_p50_ms=c50,
               core_query_p99_ms=c99, ros_rtt_over_core=p50 / c50,
               ros_overhead_p50_ms=p50 - c50, trigger_rtt_p50_ms=t50, trigger_rtt_p99_ms=t99,
               single_rtt_mesh_msg_p50_ms=m50, single_rtt_mesh_msg_p99_ms=m99,
               single_rtt_with_std_p50_ms=s50, single_rtt_with_std_p99_ms=s99,
               single_rtt_mt_client_p50_ms=mt50, single_rtt_mt_client_p99_ms=mt99,
               trigger_rtt_mt_client_p50_ms=mtt50, trigger_rtt_mt_client_p99_ms=mtt99,
               single_rtt_direct_client_p50_ms=d50, single_rtt_direct_client_p99_ms=d99,
               ros_overhead_direct_client_p50_ms=d50 - c50,
               single_rtt_direct_client_no_hot_wait_p50_ms=n50,
               single_rtt_direct_client_no_hot_wait_p99_ms=n99,
               ros_overhead_direct_client_no_hot_wait_p50_ms=n50 - c50,
               hot_wait_ms=HOT_WAIT_MS,
               trigger_rtt_direct_p50_ms=dt50, trigger_rtt_direct_p99_ms=dt99,
               single_rtt_after_idle_p50_ms=i50, single_rtt_after_idle_p99_ms=i99,
               idle_before_call_ms=1e3 * IDLE_S, burst_calls=BURST,
               client_executor='SingleThreadedExecutor (the *_mt_client series: a '
                               '2-thread MultiThreadedExecutor; *_direct_client and '
                               'trigger_rtt_direct: DirectClient, no executor)',
               single_queries=n_single, small_batch_poses=small_batch,
               small_batch_rtt_p50_ms=b50, small_batch_rtt_p99_ms=b99,
               small_batch_core_p50_ms=bc50, small_batch_core_p99_ms=bc99,
               batch_poses=n_batch, batch_ros_s=ros_batch, batch_core_s=core_batch,
               batch_ros_poses_per_s=n_batch / ros_batch,
               batch_core_poses_per_s=n_batch / core_batch,
               batch_ros_over_core=ros_batch / core_batch,
               batch_ros_ms_per_pose=1e3 * ros_batch / n_batch,
               services='contact_wrench and Trigger each in its own process')

    if not campaign:
        return out
    rng = np.random.default_rng(1)
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


if __name__ == '__main__':
    # child processes of the benchmark: the Trigger baseline service, or one load client
    if sys.argv[1] == 'trigger':
        spin_single_threaded(_trigger_node)   # the executor contact_wrench's main() spins
    elif sys.argv[1] == 'client':
        load_client(int(sys.argv[2]), int(sys.argv[3]), *sys.argv[4:5],
                    direct=sys.argv[5:6] == ['direct'])
