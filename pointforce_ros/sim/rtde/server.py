"""Network side of the emulator: RTDE, dashboard, script and fault-channel servers on loopback."""

import json
import logging
import socket
import threading
import time
from typing import Dict, List, Optional, Sequence

import numpy as np

from pointforce_ros.sim.rtde import protocol as rp
from pointforce_ros.sim.rtde.constants import (CONTROL_PORT, CONTROLLER_VERSION, DASHBOARD_PORT,
                                               DT, POLYSCOPE_TEXT, RTDE_PORT, RUNTIME_PAUSED,
                                               RUNTIME_PLAYING, SCRIPT_PORT, SERIAL_NUMBER)
from pointforce_ros.sim.rtde.controller import Controller
from pointforce_ros.sim.rtde.forces import load_force_model
from pointforce_ros.sim.rtde.motion import Kinematics

LOG = logging.getLogger('rtde_emulator')


class ClientConnection:
    """One accepted TCP connection with a non-blocking, buffered send path."""

    def __init__(self, emulator: 'Emulator', sock: socket.socket, kind: str):
        self.emulator = emulator
        self.sock = sock
        self.kind = kind
        self.send_lock = threading.Lock()
        self.pending = bytearray()
        self.closed = False

    def send(self, data: bytes) -> bool:
        """Queue ``data`` and send what the socket takes now; False once the client is gone."""
        with self.send_lock:
            if self.closed:
                return False
            self.pending.extend(data)
            return self._flush_locked()

    def flush(self) -> bool:
        """Send what is pending; return False once the connection is closed."""
        with self.send_lock:
            if self.closed:
                return False
            return self._flush_locked()

    def _flush_locked(self) -> bool:
        while self.pending:
            try:
                sent = self.sock.send(self.pending, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._close_locked()
                return False
            del self.pending[:sent]
        if len(self.pending) > 1 << 20:
            LOG.warning('%s client is not reading (%d bytes queued): dropping it',
                        self.kind, len(self.pending))
            self._close_locked()
            return False
        return True

    def close(self) -> None:
        """Close the connection (idempotent)."""
        with self.send_lock:
            self._close_locked()

    def _close_locked(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


class RtdeClient(ClientConnection):
    """One RTDE client: handshake, recipes, and its output stream at the requested rate."""

    def __init__(self, emulator, sock):
        super().__init__(emulator, sock, 'rtde')
        self.output: Optional[rp.Recipe] = None
        self.period = 1
        self.started = False
        self.inputs: Dict[int, rp.Recipe] = {}
        self.protocol_ok = False

    def serve(self) -> None:
        """Read and answer the client's packages until it disconnects."""
        buf = rp.MessageBuffer()
        while not self.closed:
            try:
                data = self.sock.recv(65536)
            except OSError:
                break
            if not data:
                break
            try:
                for msg_type, payload in buf.feed(data):
                    self._handle(msg_type, payload)
            except rp.ProtocolError as exc:
                LOG.warning('rtde client sent an invalid message (%s): closing', exc)
                break

    def _handle(self, msg_type: int, payload: bytes) -> None:
        emu = self.emulator
        if msg_type == rp.MSG_REQUEST_PROTOCOL_VERSION:
            version = int.from_bytes(payload[:2], 'big') if len(payload) >= 2 else 0
            self.protocol_ok = version == rp.PROTOCOL_VERSION
            self.send(rp.encode_message(msg_type, bytes((1 if self.protocol_ok else 0,))))
        elif msg_type == rp.MSG_GET_URCONTROL_VERSION:
            self.send(rp.encode_message(msg_type, b''.join(
                v.to_bytes(4, 'big') for v in CONTROLLER_VERSION)))
        elif msg_type == rp.MSG_SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif msg_type == rp.MSG_SETUP_INPUTS:
            self._setup_inputs(payload)
        elif msg_type == rp.MSG_START:
            self.started = self.output is not None
            self.send(rp.encode_message(msg_type, bytes((1 if self.started else 0,))))
        elif msg_type == rp.MSG_PAUSE:
            self.started = False
            self.send(rp.encode_message(msg_type, b'\x01'))
        elif msg_type == rp.MSG_DATA_PACKAGE:
            if not payload:
                return
            recipe = self.inputs.get(payload[0])
            if recipe is None:
                LOG.warning('data package for unknown input recipe %d ignored', payload[0])
                return
            try:
                values = recipe.unpack(payload[1:])
            except rp.ProtocolError as exc:
                LOG.warning('%s: ignored', exc)
                return
            emu.apply_inputs(values)
        elif msg_type == rp.MSG_TEXT_MESSAGE:
            LOG.info('rtde client text message: %r', payload)
        else:
            LOG.warning('rtde client sent unknown message type %d', msg_type)

    def _setup_outputs(self, payload: bytes) -> None:
        if len(payload) < 8:
            self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 0, []))
            return
        frequency = float(np.frombuffer(payload[:8], dtype='>f8')[0])
        names = rp.parse_names(payload[8:])
        types = rp.resolve_types(names, rp.OUTPUT_VARIABLES)
        if 'NOT_FOUND' in types or not (0.0 < frequency <= 1.0 / DT + 1e-9):
            if 'NOT_FOUND' not in types:
                LOG.warning('output frequency %.3f Hz outside (0, 500]', frequency)
            self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 0, types))
            return
        self.output = rp.Recipe(1, tuple(names), tuple(types))
        self.period = max(1, int(round(1.0 / (frequency * DT))))
        LOG.debug('output recipe at %g Hz: %s', frequency, ','.join(names))
        self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 1, types))

    def _setup_inputs(self, payload: bytes) -> None:
        names = rp.parse_names(payload)
        types = rp.resolve_types(names, rp.INPUT_VARIABLES)
        types = self.emulator.claim_inputs(self, names, types)
        if 'NOT_FOUND' in types or 'IN_USE' in types:
            self.send(rp.setup_reply(rp.MSG_SETUP_INPUTS, 0, types))
            return
        recipe_id = len(self.inputs) + 1
        self.inputs[recipe_id] = rp.Recipe(recipe_id, tuple(names), tuple(types))
        LOG.debug('input recipe %d: %s', recipe_id, ','.join(names))
        self.send(rp.setup_reply(rp.MSG_SETUP_INPUTS, recipe_id, types))


class Emulator:
    """The emulator process: listeners, client threads, the 500 Hz tick thread."""

    def __init__(self, host: str, controller: Controller, *, rtde_port: int = RTDE_PORT,
                 dashboard_port: int = DASHBOARD_PORT, script_port: int = SCRIPT_PORT,
                 control_port: int = CONTROL_PORT):
        self.host = host
        self.controller = controller
        self.ports = {'rtde': rtde_port, 'dashboard': dashboard_port, 'script': script_port,
                      'control': control_port}
        self.lock = threading.RLock()
        self.stop_event = threading.Event()
        self.clients: List[ClientConnection] = []
        self.input_owner: Dict[str, RtdeClient] = {}
        self.refuse_until = 0.0
        self.force_stall_until: Optional[float] = None
        self.stream_stall_until: Optional[float] = None
        self.late_ticks = 0
        """Controller periods skipped because the process was starved (the clock dilated)."""
        self.threads: List[threading.Thread] = []
        self.listeners: List[socket.socket] = []

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Bind every port (raises OSError if one is taken) and start all threads."""
        handlers = {'rtde': self._serve_rtde, 'dashboard': self._serve_dashboard,
                    'script': self._serve_script, 'control': self._serve_control}
        for kind, port in self.ports.items():
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind((self.host, port))
            except OSError:
                sock.close()
                for other in self.listeners:
                    other.close()
                raise
            sock.listen(16)
            sock.settimeout(0.2)
            self.listeners.append(sock)
            self._spawn(self._accept_loop, sock, kind, handlers[kind])
        self._spawn(self._tick_loop)

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        thread.start()
        self.threads.append(thread)

    def shutdown(self) -> None:
        """Stop all threads and close every socket."""
        self.stop_event.set()
        self.drop_connections()
        for sock in self.listeners:
            sock.close()
        for thread in self.threads:
            thread.join(timeout=2.0)

    # -- connection management -------------------------------------------------------------------
    def _accept_loop(self, listener: socket.socket, kind: str, handler) -> None:
        while not self.stop_event.is_set():
            try:
                sock, _ = listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            if kind != 'control' and time.monotonic() < self.refuse_until:
                sock.close()
                continue
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._spawn(self._run_client, handler, sock, kind)

    def _run_client(self, handler, sock: socket.socket, kind: str) -> None:
        client = RtdeClient(self, sock) if kind == 'rtde' else ClientConnection(self, sock, kind)
        with self.lock:
            self.clients.append(client)
        try:
            handler(client)
        except OSError:
            pass
        finally:
            client.close()
            with self.lock:
                if client in self.clients:
                    self.clients.remove(client)
                for name in [n for n, c in self.input_owner.items() if c is client]:
                    del self.input_owner[name]

    def claim_inputs(self, client: RtdeClient, names: Sequence[str],
                     types: List[str]) -> List[str]:
        """Mark input registers as written by ``client``; ``IN_USE`` where another holds one."""
        with self.lock:
            out = [('IN_USE' if typ != 'NOT_FOUND' and self.input_owner.get(name) not in
                    (None, client) else typ) for name, typ in zip(names, types)]
            if 'IN_USE' not in out and 'NOT_FOUND' not in out:
                for name in names:
                    self.input_owner[name] = client
            return out

    def drop_connections(self, refuse_s: float = 0.0) -> int:
        """Close every RTDE, dashboard and script connection; refuse new ones for a while."""
        with self.lock:
            self.refuse_until = time.monotonic() + max(0.0, refuse_s)
            victims = [c for c in self.clients if c.kind != 'control']
        for client in victims:
            client.close()
        return len(victims)

    def apply_inputs(self, values: Dict[str, object]) -> None:
        """Apply one decoded input data package to the controller registers."""
        with self.lock:
            self.controller.apply_inputs(values)

    # -- the 500 Hz loop ----------------------------------------------------------------------
    def _tick_loop(self) -> None:
        # One controller period per pass. When the process was starved for more than one
        # period the backlog is dropped rather than sent in a burst: the controller clock then
        # runs slower than the wall clock, but every period is computed and streamed (a burst
        # would make ur_rtde keep only its last package, i.e. drop samples a real controller
        # would have delivered).
        next_time = time.perf_counter()
        while not self.stop_event.is_set():
            now = time.perf_counter()
            if now < next_time:
                time.sleep(next_time - now)
            elif now - next_time > DT:
                self.late_ticks += int((now - next_time) / DT)
                next_time = now
            next_time += DT
            with self.lock:
                ctl = self.controller
                ctl.step()
                now_mono = time.monotonic()
                stall_force = self.force_stall_until is not None and (
                    self.force_stall_until == 0.0 or now_mono < self.force_stall_until)
                if stall_force and ctl.frozen_force is None:
                    ctl.frozen_force = ctl.force.copy()
                elif not stall_force and ctl.frozen_force is not None:
                    ctl.frozen_force = None
                    self.force_stall_until = None
                stall_stream = self.stream_stall_until is not None and (
                    self.stream_stall_until == 0.0 or now_mono < self.stream_stall_until)
                if not stall_stream:
                    self.stream_stall_until = None
                snapshot = ctl.outputs()
                clients = [c for c in self.clients if isinstance(c, RtdeClient)]
                messages = []
                for client in clients:
                    if client.started and not stall_stream and ctl.tick % client.period == 0:
                        messages.append((client, client.output.pack(
                            lambda name: ctl.output_value(snapshot, name))))
                    elif client.pending:
                        messages.append((client, b''))
            for client, data in messages:
                if data:
                    client.send(data)
                else:
                    client.flush()

    # -- RTDE, dashboard, script and control handlers ------------------------------------------
    def _serve_rtde(self, client: RtdeClient) -> None:
        client.serve()

    def _lines(self, client: ClientConnection):
        buf = b''
        while not client.closed:
            try:
                data = client.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b'\n' in buf:
                line, buf = buf.split(b'\n', 1)
                yield line.decode('utf-8', errors='replace').strip()

    def _serve_dashboard(self, client: ClientConnection) -> None:
        client.send(b'Connected: Universal Robots Dashboard Server\n')
        for line in self._lines(client):
            reply = self._dashboard_reply(line)
            client.send((reply + '\n').encode())
            if line == 'quit':
                return

    def _dashboard_reply(self, line: str) -> str:
        ctl = self.controller
        with self.lock:
            if line == 'PolyscopeVersion':
                return POLYSCOPE_TEXT
            if line == 'get serial number':
                return SERIAL_NUMBER
            if line == 'is in remote control':
                return 'true'
            if line == 'get robot model':
                return 'UR5'
            if line == 'robotmode':
                return 'Robotmode: RUNNING'
            if line == 'safetymode':
                return 'Safetymode: ' + ('PROTECTIVE_STOP' if ctl.protective else 'NORMAL')
            if line == 'safetystatus':
                return 'Safetystatus: ' + ('PROTECTIVE_STOP' if ctl.protective else 'NORMAL')
            if line == 'running':
                return 'Program running: ' + str(ctl.runtime_state == RUNTIME_PLAYING).lower()
            if line == 'programState':
                state = {RUNTIME_PLAYING: 'PLAYING', RUNTIME_PAUSED: 'PAUSED'}.get(
                    ctl.runtime_state, 'STOPPED')
                return f'{state} rtde_control'
            if line == 'stop':
                ctl.stop_program('dashboard stop')
                return 'Stopped'
            if line == 'pause':
                return 'Pausing program' if ctl.pause_program() else 'Failed to execute: pause'
            if line == 'play':
                return 'Starting program' if ctl.resume_program() else 'Failed to execute: play'
            if line == 'unlock protective stop':
                if ctl.unlock_protective_stop():
                    return 'Protective stop releasing'
                return 'Cannot unlock protective stop until 5s after occurrence. Always ' \
                       'inspect cause of protective stop before unlocking'
            if line == 'close safety popup':
                return 'closing safety popup'
            if line in ('power on', 'brake release', 'power off'):
                return {'power on': 'Powering on', 'brake release': 'Brake releasing',
                        'power off': 'Powering off'}[line]
            if line == 'quit':
                return 'Disconnected'
        return f"could not understand: '{line}'"

    def _serve_script(self, client: ClientConnection) -> None:
        text = ''
        while not client.closed:
            try:
                data = client.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            text += data.decode('utf-8', errors='replace')
            text = self._consume_programs(text)

    def _consume_programs(self, text: str) -> str:
        """Start every complete ``def|sec name(): ... end`` program in ``text``; keep the rest."""
        while True:
            lines = text.split('\n')
            start = next((i for i, ln in enumerate(lines[:-1])
                          if ln.startswith('def ') or ln.startswith('sec ')), None)
            if start is None:
                if len(lines) > 1:
                    for ln in lines[:-1]:
                        if ln.strip():
                            LOG.info('script line outside a program ignored: %r', ln[:80])
                    return lines[-1]
                return text
            end = next((i for i in range(start + 1, len(lines) - 1)
                        if lines[i].rstrip() == 'end'), None)
            if end is None:
                return '\n'.join(lines[start:])
            name = lines[start][4:].split('(', 1)[0].strip()
            with self.lock:
                self.controller.start_program(name)
            text = '\n'.join(lines[end + 1:])

    def _serve_control(self, client: ClientConnection) -> None:
        for line in self._lines(client):
            if not line:
                continue
            try:
                reply = self._control(line)
                reply.setdefault('ok', True)
            except (ValueError, TypeError, KeyError) as exc:
                reply = {'ok': False, 'error': f'{type(exc).__name__}: {exc}'}
            client.send((json.dumps(reply) + '\n').encode())

    def _control(self, line: str) -> dict:
        word, _, rest = line.partition(' ')
        rest = rest.strip()
        ctl = self.controller
        if word == 'ping':
            return {}
        if word == 'state':
            with self.lock:
                return {
                    'timestamp': ctl.timestamp, 'tick': ctl.tick,
                    'pose': list(ctl.kin.pose6()), 'twist': list(ctl.kin.twist6()),
                    'force': list(map(float, ctl.force)), 'raw': list(map(float, ctl.raw)),
                    'tare': list(map(float, ctl.tare)), 'runtime_state': ctl.runtime_state,
                    'protective': ctl.protective, 'moving': ctl.is_moving(),
                    'motion': ctl.motion_owner, 'out_int_0': ctl.out_int[0],
                    'clients': sorted(c.kind for c in self.clients),
                    'late_ticks': self.late_ticks, 'events': list(ctl.events)[-20:],
                }
        if word == 'protective_stop':
            with self.lock:
                ctl.protective_stop('injected on the fault channel')
            return {}
        if word == 'unlock':
            with self.lock:
                return {'released': ctl.unlock_protective_stop()}
        if word == 'program_stop':
            with self.lock:
                ctl.stop_program('injected on the fault channel')
            return {}
        if word == 'drop':
            return {'dropped': self.drop_connections(float(rest) if rest else 0.0)}
        if word == 'stall':
            what, _, secs = rest.partition(' ')
            seconds = float(secs) if secs.strip() else 0.0
            until = 0.0 if seconds <= 0.0 else time.monotonic() + seconds
            with self.lock:
                if what == 'force':
                    self.force_stall_until = until
                elif what == 'stream':
                    self.stream_stall_until = until
                else:
                    raise ValueError(f'stall: expected "force" or "stream", got {what!r}')
            return {}
        if word == 'unstall':
            with self.lock:
                self.force_stall_until = None
                self.stream_stall_until = None
                ctl.frozen_force = None
            return {}
        if word == 'model_params':
            params = json.loads(rest) if rest else {}
            with self.lock:
                setter = getattr(ctl.model, 'set_params', None)
                if setter is None:
                    raise ValueError(f'{type(ctl.model).__name__} has no set_params()')
                setter(**params)
            return {}
        if word == 'model':
            spec, _, kwargs = rest.partition(' ')
            model = load_force_model(spec, json.loads(kwargs) if kwargs.strip() else {})
            with self.lock:
                ctl.model = model
            return {}
        if word == 'set_pose':
            pose = np.asarray(json.loads(rest), dtype=float).reshape(6)
            with self.lock:
                if ctl.is_moving():
                    raise ValueError('set_pose: the TCP is moving')
                ctl.kin = Kinematics(pose)
            return {}
        raise ValueError(f'unknown command {word!r}')
