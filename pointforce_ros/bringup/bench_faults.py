"""``pointforce bench faults``: a bounded, seeded fault-and-load run on loopback (issue 16).

Everything goes through the real interfaces: the contact service and the learner run as their
own processes (``python -m pointforce_ros.nodes.<node>``, in a namespace of their own so that
nothing else on the machine answers), the poke server drives the loopback RTDE emulator through
the real ``ur_rtde``, and the bench is a DDS client in this process.

1. **Malformed contact requests** (seeded mutations of a valid sphere query: non-finite and huge
   coordinates, meshes inside the object, bad quaternions and approach vectors, far torque
   centres, broken triangles, a 2.9 m plate; batches that are empty, huge or hold one bad pose)
   and **malformed poke goals** (inverted, horizontal or tilted normals, points off the surface,
   stand-offs inside the object, bad indices, limits and speeds, NaN fields). Counted: sent,
   refused, refusals without a reason, crashes (the service process died), hangs (no answer in
   5 s), ``success=true`` answers to a malformed request (and among them non-finite or absurd
   ones), goals accepted, arm moved; a valid request is answered bit-identically before and
   after.
2. **Load**: ``clients`` concurrent clients send valid single queries; failures, p50 / p99.
3. **Faults**, each survived or not: the contact service SIGKILLed, SIGTERMed (clean exit), and
   restarted over a truncated, an empty and a garbage newest model file (seconds from the
   restart until it answers again, and on which model version: the last good one); the learner
   SIGKILLed and restarted (seconds until it publishes again; model versions whose content
   changed = versions reused); the controller killed in the middle of a push (pokes lost: a push
   whose samples are neither in the store nor in a recovery file; seconds until a poke succeeds
   again on a restarted controller); the F/T stream worker held (SIGSTOP) for 60 ms in a push
   (the poke stored, every run of slots its bag misses reported in its ``stream_losses``); the
   newest poke bag corrupted (the next poke's id is new and it is stored). The full run also
   SIGTERMs a whole ``pointforce cell`` and checks that no emulator outlives it.
4. **Memory**: peak RSS (VmHWM) of every contact service process.

"Seconds until it answers" counts from the restart (the process spawn, so it includes the Python
and rclpy start-up and DDS discovery) to the first successful round trip (the waiting client
sends a request every 50 ms and keeps the earlier ones pending: :meth:`Bench.wait_answer`);
``seconds_until_serving`` from the spawn until the node logs that it serves (model loaded,
services created).

``--quick`` runs fewer requests and goals and leaves out the whole-cell SIGTERM.
"""

import itertools
import json
import os
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional

import numpy as np
from geometry_msgs.msg import Vector3
from pointforce_interfaces.action import Poke
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.parameter import Parameter

from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.drivers.ur_arm import missing_slots, unreported_runs
from pointforce_ros.errors import DeviceFault
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import (ContactModel, content_digest, load_model, save_model,
                                        save_surface)
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.stiffness_learner import LATCHED
from pointforce_ros.pokes.store import PokeStore, read_poke_bag
from pointforce_ros.shapes import icosphere
from pointforce_ros.sim.rtde.process import (child_pids, loopback_hosts, process_alive, REPO_ROOT,
                                             start_emulator)
from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.types import Mesh, PokeGoal, Pose, Surface

HANG_S = 5.0
"""An answer slower than this is a hang."""
RETRY_S = 0.05
"""Seconds between the requests of a client waiting for a (re)started service."""
HOLD_S = 0.06
"""Seconds the F/T stream worker is held (SIGSTOP) in a push: 15 slots at 250 Hz. Its poller is
held with it, so no stall is seen: it finds the slots passed when it runs again."""
ABSURD = 1e3
"""N and N m: the sphere on the 60 mm test patch gives a few newtons."""
HUGE = [float('nan'), float('inf'), -float('inf'), 1e9, -1e9, 1e20, 1e300, -1e308]
PLATE = Mesh(vertices=[[-1.45, -1.45, 0], [1.45, -1.45, 0], [1.45, 1.45, 0], [-1.45, 1.45, 0]],
             triangles=[[0, 2, 1], [0, 3, 2]])
SPRING = {'z0': 0.04, 'k': 1000.0}
START = [0.5, 0.0, 0.1, np.pi, 0.0, 0.0]
SIZES = {False: dict(singles=520, batches=80, clients=8, queries=100, learner_pokes=5),
         True: dict(singles=40, batches=8, clients=2, queries=20, learner_pokes=3)}


# --------------------------------------------------------------------------- malformed requests
def _set(obj, axis, value):
    setattr(obj, axis, float(value))


def mutations(rng) -> List[Callable]:
    """Callables that each break a ContactWrench request in their own way (seeded choices).

    ``test/nodes/test_malformed_requests.py`` draws its 600 requests from them too.
    """
    axes = ('x', 'y', 'z')

    def position(r):
        _set(r.pose.position, rng.choice(axes), rng.choice(HUGE + [11.0, -12.0]))

    def inside(r):
        r.pose.position.z = float(rng.choice([0.04 - 0.5, 0.04 - 1.0, -0.3]))

    def orientation(r):
        q = r.pose.orientation
        q.x, q.y, q.z, q.w = [float(v) for v in rng.choice(
            [[2, 0, 0, 0], [0.5, 0, 0, 0.5], [np.nan, 0, 0, 1], [np.inf, 0, 0, 0],
             [0, 0, 0, 1e9]])]

    def approach(r):
        a = r.approach
        a.x, a.y, a.z = [float(v) for v in rng.choice(
            [[0, 0, 0], [np.nan, 0, -1], [0, 0, -2], [1, 1, 1], [0, 0, -np.inf], [1e300, 0, 0]])]

    def centre(r):
        _set(r.torque_centre, rng.choice(axes), rng.choice(HUGE + [7.0, -6.5]))

    def vertex(r):
        if not len(r.mesh.vertices):
            return r.mesh.triangles.clear() if len(r.mesh.triangles) else None
        v = r.mesh.vertices[int(rng.integers(len(r.mesh.vertices)))]
        _set(v, rng.choice(axes), rng.choice(HUGE))

    def scale(r):
        k = float(rng.choice([1e3, 1e6, 1e12]))
        for v in r.mesh.vertices:
            v.x, v.y, v.z = v.x * k, v.y * k, v.z * k

    def triangles(r):
        choice = int(rng.integers(4))
        if choice == 0:
            r.mesh.triangles = []
        elif choice == 1:
            r.mesh.vertices = []
        elif choice == 2 and len(r.mesh.triangles):
            r.mesh.triangles[int(rng.integers(len(r.mesh.triangles)))].vertex_indices = [
                0, 1, int(rng.integers(10 ** 3, 2 ** 32))]
        else:
            for v in r.mesh.vertices:
                v.x, v.y, v.z = 0.0, 0.0, 0.0

    def plate(r):
        r.mesh = mesh_to_msg(Mesh(vertices=PLATE.vertices * float(rng.choice([1.0, 100.0])),
                                  triangles=PLATE.triangles))
        r.pose.position.z = float(rng.choice([0.045 - 0.2, -1e9]))

    return [position, inside, orientation, approach, centre, vertex, scale, triangles, plate]


def good_request():
    """Return the valid sphere query (20 mm sphere pressed 3 mm into the test patch)."""
    pose = Pose(position=[0.5, 0.0, 0.057])
    return ContactWrench.Request(mesh=mesh_to_msg(icosphere(0.02, 2)), pose=pose_to_msg(pose),
                                 approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                 torque_centre=to_point(pose.position))


def malformed_batches(rng, count: int):
    """``count`` malformed ContactWrenchBatch requests: empty, a 1000-pose plate, a bad pose."""
    sphere = mesh_to_msg(icosphere(0.02, 2))
    for i in range(count):
        request = ContactWrenchBatch.Request(mesh=sphere, approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                             torque_centre=to_point([0.5, 0.0, 0.06]))
        request.poses = [pose_to_msg(Pose(position=[0.5, 0.0, 0.06 - d]))
                         for d in rng.uniform(0.0, 0.004, int(rng.integers(1, 40)))]
        kind = i % 4
        if kind == 0:
            request.poses = []
        elif kind == 1:
            request.mesh = mesh_to_msg(PLATE)
            request.poses = [pose_to_msg(Pose(position=[0.5, 0.0, 0.045]))] * 1000
        else:   # one bad pose among good ones, at a random place
            bad = request.poses[int(rng.integers(len(request.poses)))]
            if kind == 2:
                _set(bad.position, rng.choice(('x', 'y', 'z')), rng.choice(HUGE))
            else:
                bad.position.z = -0.96
        yield request


def malformed_goals(rng, quick: bool):
    """Malformed Poke goals: every bad kind once (quick) or 60 seeded picks, plus two NaN goals."""
    base = dict(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0], force_limit=3.0,
                depth_limit=0.008, speed=0.005, standoff=0.008)
    tilt = np.radians(rng.uniform(35, 89))
    bad = [
        {'normal': [0.0, 0.0, -1.0]}, {'normal': [1.0, 0.0, 0.0]},
        {'normal': [np.sin(tilt), 0.0, np.cos(tilt)]}, {'normal': [0.0, 0.0, 0.5]},
        {'point': [0.5, 0.0, 0.07]}, {'point': [0.5, 0.0, 0.0375], 'standoff': 0.004},
        {'surface_index': int(rng.integers(-2 ** 31, -1))}, {'surface_index': 30},
        {'surface_index': 2 ** 31 - 1}, {'force_limit': float(rng.choice([0.0, -1.0, 50.0]))},
        {'depth_limit': float(rng.choice([0.0, -0.001, 0.5]))},
        {'speed': float(rng.choice([0.0, -0.01, 1.0]))},
        {'standoff': float(rng.choice([0.0, 0.001, 0.2]))},
        {'point': [float(rng.choice([0.1, 0.95])), 0.0, 0.04]},
    ]
    picks = range(len(bad)) if quick else rng.integers(len(bad), size=60)
    for k in picks:
        values = dict(base)
        values.update(bad[int(k)])
        yield poke_goal_to_msg(PokeGoal(**values))
    for field in ('point', 'normal'):   # non-finite fields cannot be built as a PokeGoal
        message = poke_goal_to_msg(PokeGoal(**base))
        getattr(message, field).x = float('nan')
        yield message
    message = poke_goal_to_msg(PokeGoal(**base))
    message.header.frame_id = 'tool0'   # a frame the server does not use
    yield message


def _wrench_values(w) -> np.ndarray:
    return np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z])


# --------------------------------------------------------------------------- processes
def _env() -> dict:
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(REPO_ROOT)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return env


class NodeProcess:
    """A product node in its own process, in namespace ``ns``, logging to ``log``."""

    def __init__(self, module: str, ns: str, params: Dict[str, object], log: Path):
        """Start ``python -m pointforce_ros.nodes.<module>`` with ``params``."""
        cmd = [sys.executable, '-m', f'pointforce_ros.nodes.{module}', '--ros-args',
               '-r', f'__ns:=/{ns}']
        for key, value in params.items():
            cmd += ['-p', f'{key}:={value}']
        self.started = time.monotonic()
        self.started_wall = time.time()
        self.log = Path(log)
        self._offset = self.log.stat().st_size if self.log.exists() else 0
        with open(self.log, 'a') as out:
            self.process = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, cwd=str(REPO_ROOT),
                                            env=_env())

    def seconds_until_log(self, text: str, timeout: float = 60.0) -> float:
        """Seconds from the spawn until this process logged ``text`` (its ROS log stamp).

        NaN when no such line appears within ``timeout`` or it carries no stamp.
        """
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with open(self.log, 'rb') as fh:
                fh.seek(self._offset)
                for line in fh.read().decode(errors='replace').splitlines():
                    if text in line:
                        stamp = re.search(r'\[(\d{9,}\.\d+)\]', line)
                        return (float(stamp.group(1)) - self.started_wall if stamp
                                else float('nan'))
            time.sleep(0.01)
        return float('nan')

    def alive(self) -> bool:
        """Whether the process still runs."""
        return self.process.poll() is None

    def peak_rss_mb(self) -> float:
        """Peak resident set size so far (VmHWM), MiB; NaN once the process is gone."""
        try:
            with open(f'/proc/{self.process.pid}/status') as fh:
                for line in fh:
                    if line.startswith('VmHWM:'):
                        return int(line.split()[1]) / 1024.0
        except OSError:
            pass
        return float('nan')

    def stop(self, sig=signal.SIGTERM, timeout: float = 10.0) -> Optional[int]:
        """Send ``sig``; wait up to ``timeout`` s (then SIGKILL); return the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5.0)
                return None
        return self.process.returncode


class Bench:
    """The bench's DDS client side and the processes it started (all stopped by close)."""

    def __init__(self, work: Path, seed: int, log=print):
        """Open the client context; nothing else starts yet."""
        self.work, self.seed, self.log = Path(work), int(seed), log
        self.ns = f'bench_faults_{os.getpid()}_{seed}'
        self.client_launcher = InProcessLauncher(threads=8)
        self.node = self.client_launcher.add(Node('bench_faults_client',
                                                  context=self.client_launcher.context))
        # The endpoints the bench uses after its first fault exist before it: Fast DDS 2.14 can
        # deadlock creating an endpoint while its discovery removes a killed peer's endpoints
        # (the participant's endpoint-list mutex; eProsima/Fast-DDS#2961, #3496): seen once
        # here, the main thread stuck in create_datareader for the poke action client while a
        # discovery thread removed a killed peer's writers.
        self.statuses: List[ModelStatus] = []
        self.node.create_subscription(ModelStatus, f'/{self.ns}/stiffness_learner/model',
                                      self.statuses.append, LATCHED)
        self.poke_client = ActionClient(self.node, Poke, f'/{self.ns}/poke_server/poke')
        self.processes: List[NodeProcess] = []
        self.server_launcher = None
        self.emulator = None
        self.peak_rss_mb = 0.0

    # ------------------------------------------------------------------ helpers
    def call(self, client, request, timeout: float = HANG_S):
        """Return ``(seconds, response)``; response ``None`` when none came within ``timeout``."""
        done = threading.Event()
        start = time.perf_counter()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())   # event-driven: no poll period
        if not done.wait(timeout):
            client.remove_pending_request(future)
            return time.perf_counter() - start, None
        return time.perf_counter() - start, future.result()

    def start_node(self, module: str, **params) -> NodeProcess:
        """Start a node process (see :class:`NodeProcess`) and remember it."""
        proc = NodeProcess(module, self.ns, params, self.work / f'{module}.log')
        self.processes.append(proc)
        return proc

    def note_rss(self, proc: NodeProcess) -> None:
        """Fold ``proc``'s peak RSS into the bench's peak."""
        rss = proc.peak_rss_mb()
        if np.isfinite(rss):
            self.peak_rss_mb = max(self.peak_rss_mb, rss)

    def close(self):
        """Stop every process and context the bench started."""
        for proc in self.processes:
            proc.stop(signal.SIGKILL, 5.0)
        if self.server_launcher is not None:
            self.server_launcher.close()
        if self.emulator is not None:
            self.emulator.stop()
        self.client_launcher.close()

    # ------------------------------------------------------------------ the contact service
    def contact_clients(self):
        """Single and batch clients of the namespaced contact service."""
        base = f'/{self.ns}/contact_wrench'
        return (self.node.create_client(ContactWrench, f'{base}/contact_wrench'),
                self.node.create_client(ContactWrenchBatch, f'{base}/contact_wrench_batch'))

    def wait_answer(self, client, request, started: float, timeout: float = 60.0,
                    retry: float = RETRY_S):
        """Call until a successful answer; return ``(seconds since started, response)``.

        A request sent before the restarted server is matched, or to the killed one (discovery
        lists it for a while), is never answered; so a new request goes out every ``retry``
        seconds while the earlier ones stay pending, and the first successful answer to any of
        them counts, stamped when it arrives. The time is the service's to within ``retry``,
        not a multiple of a per-call time-out (0.5 s per lost request before). NaN and
        ``None`` when no answer came within ``timeout``.
        """
        answers = queue.SimpleQueue()
        pending = []
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                if client.service_is_ready():
                    future = client.call_async(request)
                    future.add_done_callback(lambda f: answers.put((time.monotonic(), f)))
                    pending.append(future)
                until = min(time.monotonic() + retry, deadline)
                while (left := until - time.monotonic()) > 0:
                    try:
                        stamp, future = answers.get(timeout=left)
                    except queue.Empty:
                        break
                    response = future.result()
                    if response is not None and response.success:
                        return stamp - started, response
        finally:
            for future in pending:
                if not future.done():
                    client.remove_pending_request(future)
        return float('nan'), None


def _malformed_contact(bench: Bench, service: NodeProcess, single, batch, sizes, rng) -> dict:
    out = dict(sent=0, refused=0, refused_without_reason=0, crashes=0, hangs=0,
               success_on_malformed=0, success_nonfinite_or_absurd=0, slowest_s=0.0)
    muts = mutations(rng)
    requests = []
    for _ in range(sizes['singles']):
        request = good_request()
        for k in rng.choice(len(muts), size=int(rng.integers(1, 4)), replace=False):
            muts[k](request)
        requests.append((single, request))
    requests += [(batch, r) for r in malformed_batches(rng, sizes['batches'])]
    for client, request in requests:
        if not service.alive():
            out['crashes'] += 1
            break
        seconds, response = bench.call(client, request)
        out['sent'] += 1
        out['slowest_s'] = max(out['slowest_s'], seconds)
        if response is None:
            out['hangs'] += 1
            continue
        if response.success:
            out['success_on_malformed'] += 1
            values = (_wrench_values(response.wrench) if hasattr(response, 'wrench') else
                      np.concatenate([_wrench_values(w) for w in response.wrenches] or [[0.0]]))
            if not np.all(np.isfinite(values)) or np.max(np.abs(values)) > ABSURD:
                out['success_nonfinite_or_absurd'] += 1
        else:
            out['refused'] += 1
            if not response.message or 'Wrench.' in response.message:
                out['refused_without_reason'] += 1
    if not service.alive() and out['crashes'] == 0:
        out['crashes'] = 1
    out['slowest_s'] = round(out['slowest_s'], 3)
    return out


def _load(bench: Bench, single, sizes) -> dict:
    """``clients`` threads x ``queries`` valid single queries at once."""
    clients = [bench.node.create_client(ContactWrench, single.srv_name)
               for _ in range(sizes['clients'])]
    times, failures = [], []
    lock = threading.Lock()

    def worker(client):
        request = good_request()
        for _ in range(sizes['queries']):
            seconds, response = bench.call(client, request)
            with lock:
                times.append(seconds)
                if response is None or not response.success:
                    failures.append(getattr(response, 'message', 'no answer'))
    threads = [threading.Thread(target=worker, args=(c,)) for c in clients]
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - start
    for c in clients:
        bench.node.destroy_client(c)
    ms = 1e3 * np.array(times)
    return dict(clients=sizes['clients'], queries_each=sizes['queries'], failures=len(failures),
                p50_ms=round(float(np.percentile(ms, 50)), 2),
                p99_ms=round(float(np.percentile(ms, 99)), 2),
                calls_per_s=round(len(times) / wall, 1))


def _corrupt(path: Path, how: str, rng) -> None:
    if how == 'truncated':
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif how == 'empty':
        path.write_bytes(b'')
    else:
        path.write_bytes(rng.bytes(4096))


def contact_service_faults(bench: Bench, sizes, rng) -> dict:
    """Malformed requests, load, and the contact service's faults (kill, SIGTERM, bad files)."""
    models = bench.work / 'models'
    good = patch_contact_model(spacing=0.003)
    save_model(good, models)
    save_model(ContactModel(surface=good.surface, response=good.response, shape_constant=0.005,
                            version=1), models)   # two versions on disk: the newer is good
    last_good = max(int(p.stem.split('-v')[1]) for p in models.glob('model-v*.npz'))
    single, batch = bench.contact_clients()
    service = bench.start_node('contact_wrench', model_dir=models)
    request = good_request()
    up_s, before = bench.wait_answer(single, request, service.started)
    if before is None:
        raise DeviceFault(f'the contact service did not answer within 60 s (log '
                          f'{service.log})')
    bench.log(f'[bench faults] contact service up in {up_s:.1f} s, model v{before.model_version}')
    report = {'startup_s': round(up_s, 2)}
    report['malformed_requests'] = _malformed_contact(bench, service, single, batch, sizes, rng)
    _, after = bench.call(single, request)
    report['malformed_requests']['valid_bit_identical_after'] = bool(
        after is not None and after.success and after.model_version == before.model_version
        and np.array_equal(_wrench_values(after.wrench), _wrench_values(before.wrench)))
    report['load'] = _load(bench, single, sizes)
    bench.note_rss(service)
    faults = {}

    def restart(name, sig, prepare=None):
        bench.note_rss(service_box[0])
        code = service_box[0].stop(sig, 10.0)
        if prepare is not None:
            prepare()
        proc = bench.start_node('contact_wrench', model_dir=models)
        service_box[0] = proc
        seconds, answer = bench.wait_answer(single, request, proc.started)
        faults[name] = dict(
            exit_code=code, seconds_until_answer=round(seconds, 2),
            seconds_until_serving=round(proc.seconds_until_log('serving contact wrenches'), 2),
            answered_on_version=None if answer is None else int(answer.model_version),
            on_last_good_model=bool(answer is not None and answer.model_version == last_good),
            bit_identical=bool(answer is not None and np.array_equal(
                _wrench_values(answer.wrench), _wrench_values(before.wrench))))
        bench.log(f'[bench faults] {name}: {faults[name]}')

    service_box = [service]
    restart('killed_service', signal.SIGKILL)
    restart('sigterm_service', signal.SIGTERM)
    for how in ('truncated', 'empty', 'garbage'):
        newest = []

        def prepare(how=how, newest=newest):
            # a newer model lands, then its file is damaged: the service must fall back
            newest.append(save_model(ContactModel(surface=good.surface, response=good.response,
                                                  shape_constant=0.006, version=last_good + 1),
                                     models))
            _corrupt(newest[0], how, rng)
        restart(f'{how}_model_file', signal.SIGKILL, prepare=prepare)
        faults[f'{how}_model_file']['quarantined'] = bool(
            not newest[0].exists()
            and any((models / 'quarantine').glob(f'{newest[0].name}*')))
    bench.note_rss(service_box[0])
    report['faults'] = faults
    return report


# --------------------------------------------------------------------------- the learner
def learner_faults(bench: Bench, sizes) -> dict:
    """SIGKILL the learner and restart it: seconds until it publishes, versions reused."""
    work = bench.work / 'learner'
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 15), np.linspace(-0.035, 0.035, 15))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    save_surface(Surface(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1))),
                 work / 'surface.npz')
    obj = halfspace_object(HalfSpaceContact(z0=0.04, ripple=0.3),
                           region=((0.47, 0.53), (-0.03, 0.03)))
    store = PokeStore(work / 'pokes')
    for record in simulate_campaign(obj, load_scenario('clean'), count=sizes['learner_pokes'],
                                    seed=bench.seed, force_limit=3.0, depth_limit=0.01,
                                    speed=0.004, gap=0.5):
        store.add(record)
    statuses = bench.statuses
    params = dict(store_dir=work / 'pokes', model_dir=work / 'models',
                  surface_file=work / 'surface.npz', poll_period=600.0)
    want = sizes['learner_pokes']
    learner = bench.start_node('stiffness_learner', **params)
    bench.client_launcher.wait_for(lambda: statuses and statuses[-1].num_pokes == want, 120,
                                   'the learner\'s first model')
    first = statuses[-1]
    digests = {p.name: content_digest(load_model(p)) for p in (work / 'models').glob('*.npz')}
    learner.stop(signal.SIGKILL)
    statuses.clear()
    learner = bench.start_node('stiffness_learner', **params)
    try:
        bench.client_launcher.wait_for(lambda: statuses and statuses[-1].num_pokes == want, 120,
                                       'the restarted learner\'s model')
        seconds = time.monotonic() - learner.started
        again = statuses[-1]
    except RuntimeError:
        seconds, again = float('nan'), None
    after = {p.name: content_digest(load_model(p)) for p in (work / 'models').glob('*.npz')}
    reused = sum(1 for name, digest in digests.items() if after.get(name) not in (None, digest))
    learner.stop(signal.SIGTERM)
    return dict(killed_learner=dict(
        seconds_until_model=round(seconds, 2), version_before=int(first.version),
        version_after=None if again is None else int(again.version),
        same_model=bool(again is not None and again.model_path == first.model_path),
        versions_reused=reused, model_files=len(after)))


# --------------------------------------------------------------------------- the poke server
def _poke(bench: Bench, client, goal, on_feedback=None, timeout: float = 60.0):
    handle = bench.client_launcher.wait_future(
        client.send_goal_async(goal, feedback_callback=on_feedback), 20, 'goal response')
    if not handle.accepted:
        return None
    return bench.client_launcher.wait_future(handle.get_result_async(), timeout,
                                             'poke result').result


def poke_faults(bench: Bench, rng, quick: bool) -> dict:
    """Malformed goals, a dead controller mid-push and a corrupt newest bag, on the emulator."""
    hosts = loopback_hosts(bench.seed + 7)
    spring = dict(force_model='pointforce_ros.sim.rtde.forces:HalfSpaceSpring',
                  force_model_kwargs=SPRING, initial_pose=START)
    bench.emulator = start_emulator(bench.work / 'logs', hosts=hosts, **spring)
    store_dir = bench.work / 'pokes'
    bench.server_launcher = InProcessLauncher(threads=4, args=['--ros-args', '-r',
                                                               f'__ns:=/{bench.ns}'])
    server = bench.server_launcher.add(PokeServerNode(
        context=bench.server_launcher.context, parameter_overrides=[
            Parameter('robot_ip', value=bench.emulator.host),
            Parameter('store_dir', value=str(store_dir))]), isolated=True)
    pts = np.column_stack([np.linspace(0.45, 0.55, 30), np.zeros(30), np.full(30, 0.04)])
    server.surface = Surface(points=pts, normals=np.tile([0, 0, 1.0], (30, 1)))
    client = bench.poke_client
    if not client.wait_for_server(timeout_sec=20.0):
        raise DeviceFault('the poke server did not appear within 20 s')
    before = np.asarray(bench.emulator.control.state()['pose'], dtype=float)
    goals = dict(sent=0, rejected=0, accepted=0, hangs=0)
    for goal in malformed_goals(rng, quick):
        goals['sent'] += 1
        future = client.send_goal_async(goal)
        try:
            handle = bench.client_launcher.wait_future(future, HANG_S, 'goal response')
        except RuntimeError:
            goals['hangs'] += 1
            continue
        if handle.accepted:
            goals['accepted'] += 1
            bench.client_launcher.wait_future(handle.get_result_async(), 60, 'result')
        else:
            goals['rejected'] += 1
    moved = np.asarray(bench.emulator.control.state()['pose'], dtype=float)
    goals['arm_moved_mm'] = round(1e3 * float(np.linalg.norm(moved[:3] - before[:3])), 3)
    goals['lock_free_after'] = not server._busy.locked()

    good = dict(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0], force_limit=2.0,
                depth_limit=0.008, speed=0.005, standoff=0.008)
    results = []   # every poke result: a push with samples must be stored or kept

    def poke(on_feedback=None, **overrides):
        result = _poke(bench, client, poke_goal_to_msg(PokeGoal(**dict(good, **overrides))),
                       on_feedback)
        if result is not None:
            results.append(result)
        return result

    def lost(result) -> bool:
        """Tell whether a push recorded samples that are neither stored readably nor kept."""
        if result is None or result.samples == 0:
            return False
        if result.poke_id:
            try:
                return len(read_poke_bag(store_dir / result.poke_id)) != result.samples
            except Exception:  # noqa: BLE001 - an unreadable bag is a lost poke
                return result.poke_id != corrupted[0]   # the bench damaged that one itself
        return 'kept in' not in result.message

    corrupted = ['']
    first = poke()
    held_up = _held_up_stream(server, poke, store_dir)
    # the controller dies in the middle of a push (a push the loaded machine aborts before the
    # kill, e.g. a stalled stream, is tried again, at most 3 times)
    fired = threading.Event()

    def kill_mid_push(msg):
        if msg.feedback.phase == 'push' and msg.feedback.depth > 0.0005 and not fired.is_set():
            fired.set()
            bench.emulator.process.kill()
    dead, attempts = None, 0
    while not fired.is_set() and attempts < 3:
        attempts += 1
        dead = poke(kill_mid_push, speed=0.003)
    killed_at = time.monotonic()
    bench.emulator.stop()
    bench.emulator = start_emulator(bench.work / 'logs',
                                    hosts=itertools.chain([bench.emulator.host], hosts), **spring)
    server.robot_ip = bench.emulator.host   # the next goal reconnects there
    again, tries = None, 0
    while tries < 5 and (again is None or again.outcome != 'force_limit'):
        tries += 1
        again = poke()
    dead_controller = dict(
        killed_mid_push=fired.is_set(), attempts=attempts,
        outcome=None if dead is None else dead.outcome,
        message=None if dead is None else dead.message[:160],
        samples=None if dead is None else int(dead.samples),
        pokes_lost=int(lost(dead)),
        seconds_until_poke_again=round(time.monotonic() - killed_at, 2),
        pokes_to_recover=tries)
    # the newest bag is corrupted; the next poke must get a new id and be stored
    ids = PokeStore(store_dir).ids()
    corrupted[0] = ids[-1]
    for mcap in (store_dir / ids[-1]).glob('*.mcap'):
        mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 3])
    nxt, tries_after = None, 0
    while tries_after < 3 and (nxt is None or not nxt.poke_id):
        tries_after += 1
        nxt = poke()
    reloaded = PokeStore(store_dir)   # a restarted server or learner: the bad bag is set aside
    corrupt_bag = dict(corrupted=ids[-1], next_id=None if nxt is None else nxt.poke_id,
                       pokes_to_store=tries_after,
                       id_reused=bool(nxt is not None and nxt.poke_id in ids),
                       pokes_lost=int(nxt is None or not nxt.poke_id or lost(nxt)),
                       quarantined_on_reload=bool(
                           ids[-1] not in reloaded.ids()
                           and any((store_dir / 'quarantine').glob(f'{ids[-1]}*'))))
    all_ids = [r.poke_id for r in results if r.poke_id]
    summary = dict(pokes_sent=len(results), pushes_with_samples=sum(r.samples > 0
                                                                    for r in results),
                   pokes_lost=sum(lost(r) for r in results),
                   ids_reused=len(all_ids) - len(set(all_ids)),
                   outcomes=sorted(r.outcome for r in results))
    return dict(malformed_goals=goals, first_poke=None if first is None else first.outcome,
                pokes=summary, faults=dict(dead_controller_mid_poke=dead_controller,
                                           corrupt_newest_bag=corrupt_bag,
                                           stream_held_up_mid_push=held_up))


def _held_up_stream(server, poke, store_dir: Path) -> dict:
    """Stop the F/T stream worker for :data:`HOLD_S` in a push (SIGSTOP: a loaded machine).

    Its slots pass unread (ur_rtde keeps only the newest sample); the poke must be stored
    with each run of empty slots reported in ``meta['stream_losses']``. Counted: the slots
    the bag misses (:func:`~pointforce_ros.drivers.ur_arm.missing_slots`), the runs of them
    not reported with the same size, the longest hold reported, and whether the poke was kept.
    """
    fired = threading.Event()

    def hold_mid_push(msg):
        if msg.feedback.phase == 'push' and msg.feedback.depth > 0.0005 and not fired.is_set():
            fired.set()
            pid = server._arm.stream_pid
            os.kill(pid, signal.SIGSTOP)
            try:
                time.sleep(HOLD_S)
            finally:
                os.kill(pid, signal.SIGCONT)
    result = poke(hold_mid_push)
    out = dict(held_mid_push=fired.is_set(), hold_s=HOLD_S,
               outcome=None if result is None else result.outcome,
               message='' if result is None else result.message[:160],
               stored=bool(result is not None and result.poke_id))
    if not out['stored']:
        return out
    record = read_poke_bag(store_dir / result.poke_id)
    after, count = missing_slots(record.t_controller)
    losses = record.meta.get('stream_losses', [])
    return dict(out, slots_missed=int(count.sum()), runs=len(after),
                runs_unreported=len(unreported_runs(record.t_controller, losses)),
                longest_held_ms=round(1e3 * max((x[2] for x in losses), default=0.0), 1))


# --------------------------------------------------------------------------- the whole cell
def cell_sigterm(bench: Bench) -> dict:
    """SIGTERM a ``pointforce cell``: its exit code and whether its emulator outlived it."""
    cell = subprocess.Popen([sys.executable, '-m', 'pointforce_ros.bringup.cli', 'cell',
                             '--object', 'halfspace', '--scenario', 'clean', '--out',
                             str(bench.work / 'cell')], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, cwd=str(REPO_ROOT), env=_env())
    try:
        deadline = time.monotonic() + 180
        line = ''
        while time.monotonic() < deadline:
            line = cell.stdout.readline()
            if line.startswith('[cell] running') or not line:
                break
        if not line.startswith('[cell] running'):
            return dict(started=False)
        emulators = child_pids(cell.pid, 'pointforce_ros.sim.rtde.emulator')
        cell.send_signal(signal.SIGTERM)
        code = cell.wait(30)
        deadline = time.monotonic() + 10
        while any(process_alive(p) for p in emulators) and time.monotonic() < deadline:
            time.sleep(0.1)
        return dict(started=True, exit_code=code,
                    orphan_emulators=sum(process_alive(p) for p in emulators))
    finally:
        if cell.poll() is None:
            cell.kill()
            cell.wait(10)


# --------------------------------------------------------------------------- the bench
def bench_faults(quick: bool = False, seed: int = 16, out: Optional[str] = None,
                 log=None) -> dict:
    """Run the fault-and-load bench; return its counts (one JSON object, see the module doc).

    Args:
        quick: fewer requests, goals and clients, no whole-cell SIGTERM.
        seed: seed of every random choice (mutations, goals, simulated pokes).
        out: working directory (default: a temporary one, removed afterwards).
        log: progress lines (default: stderr).

    """
    log = log or (lambda line: print(line, file=sys.stderr, flush=True))
    sizes = SIZES[bool(quick)]
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(prefix='bench_faults_') as tmp:
        work = Path(out) if out else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        (work / 'logs').mkdir(exist_ok=True)
        start = time.monotonic()
        bench = Bench(work, seed, log)
        try:
            contact = contact_service_faults(bench, sizes, rng)
            log('[bench faults] contact service done')
            learner = learner_faults(bench, sizes)
            log('[bench faults] learner done')
            pokes = poke_faults(bench, rng, bool(quick))
            log('[bench faults] poke server done')
            cell = {} if quick else {'sigterm_cell': cell_sigterm(bench)}
        finally:
            bench.close()
    faults = dict(contact['faults'], **learner, **pokes['faults'], **cell)
    lost = pokes['pokes']['pokes_lost']   # every poke the bench sent, the faults' ones too
    serving = [f['seconds_until_serving'] for f in contact['faults'].values()]
    reused = sum(f.get('versions_reused', 0) for f in faults.values()) + (
        pokes['pokes']['ids_reused'])
    back = [f['seconds_until_answer'] for f in contact['faults'].values()]
    malformed = contact['malformed_requests']
    goals = pokes['malformed_goals']
    return {
        'quick': bool(quick), 'seed': int(seed),
        'malformed_requests': malformed, 'malformed_goals': goals, 'load': contact['load'],
        'pokes': pokes['pokes'],
        'faults': faults,
        'contact_service_startup_s': contact['startup_s'],
        'contact_service_peak_rss_mb': round(bench.peak_rss_mb, 1),
        'pokes_lost': int(lost), 'versions_or_ids_reused': int(reused),
        'service_back_max_s': round(float(np.nanmax(back)), 2) if back else None,
        'service_serving_max_s': round(float(np.nanmax(serving)), 2) if serving else None,
        'crashes': int(malformed['crashes']), 'hangs': int(malformed['hangs'] + goals['hangs']),
        'success_on_malformed': int(malformed['success_on_malformed'] + goals['accepted']),
        'seconds': round(time.monotonic() - start, 1),
    }


if __name__ == '__main__':
    print(json.dumps(bench_faults(quick='--quick' in sys.argv), sort_keys=True))
