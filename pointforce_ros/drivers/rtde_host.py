"""ur_rtde's control and status interfaces in a process of their own, called through a socket.

Why: ur_rtde is C++ with threads of its own. When a controller dies or stalls mid-session, an
``RTDEControlInterface`` or ``RTDEReceiveInterface`` can end in a state where its destructor
throws; a throwing destructor is ``std::terminate``, and that aborts whatever process holds the
object. Seen here: the poke server aborted in ``destroy_node`` when it dropped its arm after a
stalled stream, and took the whole test session (on a cell: every node of the process) down
with it. So the node process never holds a ur_rtde object. :class:`RtdeHost` starts
``python -m pointforce_ros.drivers.rtde_host`` and hands out :class:`RemoteInterface` proxies
that forward each method call; the host process serves the control and the status interface on
two threads (ur_rtde releases the GIL in its blocking calls, so a synchronous ``moveL`` does not
hold up a status query). The host ends with ``os._exit`` and never runs those destructors; if it
dies anyway, every later call raises ``RuntimeError`` naming the exit code, which the driver
already reads as a lost connection.

Wire format on each ``socketpair``: a 4-byte little-endian length, then a pickle. Requests are
``(method, args)``; replies ``('ok', value)`` or ``('error', exception class name, message)``.
The first message on the control socket is ``('ready', None)`` or the constructor's error.
Pickle is safe here: both ends are this package, over a private socket pair.

This module and :mod:`pointforce_ros.drivers.ur_arm` (for its stream worker process) are the
only ones that import ``rtde_control`` / ``rtde_receive``; importing them creates no object.
"""

import json
import os
import pickle
import signal
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path
from typing import Optional, Sequence

import rtde_control
import rtde_receive

_LENGTH = struct.Struct('<I')
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])
_ERRORS = {'ValueError': ValueError, 'TypeError': TypeError}
"""Exception classes re-raised as themselves; every other one becomes ``RuntimeError``."""


def _send(sock: socket.socket, message) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    sock.sendall(_LENGTH.pack(len(data)) + data)


def _recv_exact(sock: socket.socket, size: int) -> bytes:
    chunks = []
    while size:
        chunk = sock.recv(size)
        if not chunk:
            raise EOFError('the other end closed the socket')
        chunks.append(chunk)
        size -= len(chunk)
    return b''.join(chunks)


def _recv(sock: socket.socket):
    (size,) = _LENGTH.unpack(_recv_exact(sock, _LENGTH.size))
    return pickle.loads(_recv_exact(sock, size))


class RemoteInterface:
    """A ur_rtde interface in the host process: ``proxy.moveL(pose, 0.1, 1.0, True)``.

    ``rtde_host`` is the :class:`RtdeHost` that holds it. Calls are serialised per interface
    (one socket each). A ur_rtde exception is re-raised
    with its message (``RuntimeError`` unless it was a ``ValueError`` or ``TypeError``); a
    host process that is gone, or a call past ``timeout``, raises ``RuntimeError`` and leaves
    the proxy broken (every later call raises at once).
    """

    def __init__(self, owner: 'RtdeHost', sock: socket.socket, name: str):
        self.rtde_host = owner
        self._sock = sock
        self._name = name
        self._lock = threading.Lock()
        self._broken: Optional[str] = None

    def __getattr__(self, method: str):
        if method.startswith('_'):
            raise AttributeError(method)

        def call(*args):
            return self.call(method, args)
        call.__name__ = method
        return call

    def call(self, method: str, args: Sequence = (), timeout: Optional[float] = None):
        """Run ``method(*args)`` on the remote interface; see the class for errors."""
        with self._lock:
            if self._broken is not None:
                raise RuntimeError(f'{self._name}.{method}: {self._broken}')
            try:
                self._sock.settimeout(timeout)
                _send(self._sock, (method, tuple(args)))
                reply = _recv(self._sock)
            except socket.timeout:
                self._broken = f'no reply within {timeout:g} s; the interface host was abandoned'
                raise RuntimeError(f'{self._name}.{method}: {self._broken}') from None
            except (OSError, EOFError, pickle.UnpicklingError) as exc:
                self._broken = ('the ur_rtde host process is gone '
                                f'({self.rtde_host.exit_text(wait=1.0)})')
                raise RuntimeError(f'{self._name}.{method}: {self._broken}') from exc
        if reply[0] == 'ok':
            return reply[1]
        raise _ERRORS.get(reply[1], RuntimeError)(reply[2])

    def close(self) -> None:
        """Close this end of the socket (idempotent)."""
        with self._lock:
            self._broken = self._broken or 'closed'
            self._sock.close()


class RtdeHost:
    """Start the host process and connect ``RTDEControlInterface`` + ``RTDEReceiveInterface``.

    Args:
        host: controller address.
        frequency: RTDE frequency of both interfaces, Hz.
        variables: output recipe of the status interface (ur_rtde variable names; empty:
            every variable).
        timeout: deadline for both interfaces to connect, s.

    Attributes:
        ctrl, rx: :class:`RemoteInterface` proxies of the two interfaces.

    Raises:
        RuntimeError, ValueError: what ur_rtde raised while connecting (its message), or the
            host process failed to start or answer within ``timeout``.

    """

    def __init__(self, host: str, frequency: float, variables: Sequence[str], timeout: float):
        ctrl_parent, ctrl_child = socket.socketpair()
        rx_parent, rx_child = socket.socketpair()
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(
            [_PACKAGE_ROOT] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
        cmd = [sys.executable, '-m', 'pointforce_ros.drivers.rtde_host', host, repr(frequency),
               json.dumps(list(variables)), str(ctrl_child.fileno()), str(rx_child.fileno()),
               str(os.getpid())]
        try:
            self.process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, env=env,
                                            pass_fds=(ctrl_child.fileno(), rx_child.fileno()))
        except OSError as exc:
            for sock in (ctrl_parent, ctrl_child, rx_parent, rx_child):
                sock.close()
            raise RuntimeError(f'cannot start the ur_rtde host process: {exc}') from exc
        finally:
            ctrl_child.close()
            rx_child.close()
        self.ctrl = RemoteInterface(self, ctrl_parent, 'RTDEControlInterface')
        self.rx = RemoteInterface(self, rx_parent, 'RTDEReceiveInterface')
        try:
            ctrl_parent.settimeout(timeout)
            first = _recv(ctrl_parent)
        except socket.timeout:
            self.close(disconnect=False)
            raise RuntimeError(f'ur_rtde did not connect to {host} within {timeout:g} s') \
                from None
        except (OSError, EOFError) as exc:
            self.close(disconnect=False)
            raise RuntimeError('the ur_rtde host process ended while connecting '
                               f'({self.exit_text(wait=1.0)})') from exc
        if first[0] != 'ready':
            self.close(disconnect=False)
            raise _ERRORS.get(first[1], RuntimeError)(first[2])

    def alive(self) -> bool:
        """Return True while the host process runs."""
        return self.process.poll() is None

    def exit_text(self, wait: float = 0.0) -> str:
        """Say how the host process ended, waiting up to ``wait`` s for it to end."""
        try:
            code = self.process.wait(wait) if wait > 0.0 else self.process.poll()
        except subprocess.TimeoutExpired:
            code = None
        if code is None:
            return 'still running'
        if code < 0:
            return f'killed by signal {-code}'
        return f'exit code {code}'

    def close(self, disconnect: bool = True, timeout: float = 5.0) -> None:
        """Disconnect both interfaces (each at most ``timeout`` s) and end the process."""
        if disconnect and self.alive():
            threads = [threading.Thread(target=_quiet_disconnect, args=(proxy, timeout))
                       for proxy in (self.ctrl, self.rx)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
        self.ctrl.close()
        self.rx.close()
        try:
            self.process.wait(2.0)      # the host leaves on EOF of its sockets
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(5.0)


def _quiet_disconnect(proxy: RemoteInterface, timeout: float) -> None:
    try:
        proxy.call('disconnect', (), timeout)
    except (RuntimeError, ValueError, TypeError):
        pass


# ------------------------------------------------------------------------------------------------
# the host process

def _serve(sock: socket.socket, iface, done: threading.Event) -> None:
    """Answer calls on ``sock`` until it closes."""
    try:
        while True:
            try:
                method, args = _recv(sock)
            except (OSError, EOFError):
                return
            try:
                reply = ('ok', getattr(iface, method)(*args))
            except Exception as exc:   # noqa: BLE001 - every failure goes back to the caller
                reply = ('error', type(exc).__name__, str(exc))
            try:
                _send(sock, reply)
            except OSError:
                return
    finally:
        done.set()


_KEPT = []
"""The host's interfaces, referenced until ``os._exit`` so that no destructor of theirs runs."""


def _host(argv: Sequence[str]) -> int:
    """Entry of the host process (see the module docstring); returns its exit code."""
    host, frequency = argv[0], float(argv[1])
    variables = json.loads(argv[2])
    ctrl_sock = socket.socket(fileno=int(argv[3]))
    rx_sock = socket.socket(fileno=int(argv[4]))
    parent = int(argv[5])
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # a Ctrl-C is the parent's to handle
    try:
        ctrl = rtde_control.RTDEControlInterface(host, frequency)
        _KEPT.append(ctrl)
        rx = rtde_receive.RTDEReceiveInterface(host, frequency, variables)
        _KEPT.append(rx)
    except Exception as exc:   # noqa: BLE001 - the parent re-raises it
        try:
            _send(ctrl_sock, ('error', type(exc).__name__, str(exc)))
        except OSError:
            pass
        return 1
    _send(ctrl_sock, ('ready', None))
    done = threading.Event()
    for sock, iface in ((ctrl_sock, ctrl), (rx_sock, rx)):
        threading.Thread(target=_serve, args=(sock, iface, done), daemon=True).start()
    while not done.wait(0.5):
        if os.getppid() != parent:
            break
    return 0


if __name__ == '__main__':
    sys.stdout.flush()
    code = _host(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)   # never run ur_rtde's destructors (see the module docstring)
