"""Client of the emulator's fault-injection channel (port 30099)."""

import json
import socket
from typing import Sequence


from pointforce_ros.sim.rtde.constants import CONTROL_PORT


class EmulatorControl:
    """Client of the emulator's fault-injection channel (see the module docstring).

    Every call opens a short TCP connection, so the object is cheap and thread-safe.

    Raises:
        ConnectionError: the channel does not answer within ``timeout`` seconds.
        RuntimeError: the emulator rejected the command (its message is included).

    """

    def __init__(self, host: str, port: int = CONTROL_PORT, timeout: float = 2.0):
        self.host, self.port, self.timeout = host, port, timeout

    def command(self, line: str) -> dict:
        """Send one command line and return the decoded JSON reply."""
        try:
            with socket.create_connection((self.host, self.port), timeout=self.timeout) as s:
                s.sendall(line.encode() + b'\n')
                buf = b''
                while b'\n' not in buf:
                    chunk = s.recv(65536)
                    if not chunk:
                        break
                    buf += chunk
        except OSError as exc:
            raise ConnectionError(f'rtde_emulator control channel {self.host}:{self.port}: '
                                  f'{exc}') from exc
        if b'\n' not in buf:
            raise ConnectionError(f'rtde_emulator control channel {self.host}:{self.port}: '
                                  'connection closed without a reply')
        reply = json.loads(buf.split(b'\n', 1)[0])
        if not reply.get('ok'):
            raise RuntimeError(f'rtde_emulator rejected {line!r}: {reply.get("error")}')
        return reply

    def state(self) -> dict:
        """Return a snapshot: pose, twist, force, modes, clients, recent events."""
        return self.command('state')

    @staticmethod
    def starved_share(before: dict, after: dict) -> float:
        """Return the share of periods between two :meth:`state` snapshots dropped starved.

        The emulator drops a period when its process was starved (its clock dilates). A
        starved emulator's stream says nothing about a reader's losses: tests judge stream
        quality only where this is small.
        """
        ticks = after['tick'] - before['tick']
        dropped = after['late_ticks'] - before['late_ticks']
        return dropped / max(ticks + dropped, 1)

    def protective_stop(self) -> None:
        """Inject a protective stop."""
        self.command('protective_stop')

    def unlock(self) -> bool:
        """Release the protective stop; False if there was none."""
        return bool(self.command('unlock')['released'])

    def program_stop(self) -> None:
        """Stop the control program."""
        self.command('program_stop')

    def drop(self, refuse_s: float = 0.0) -> int:
        """Close every client connection, refuse new ones for ``refuse_s``; return count."""
        return int(self.command(f'drop {refuse_s}')['dropped'])

    def stall(self, what: str = 'force', seconds: float = 0.0) -> None:
        """Freeze the force (``force``) or stop the data (``stream``); 0 s = until unstall."""
        self.command(f'stall {what} {seconds}')

    def unstall(self) -> None:
        """End both kinds of stall."""
        self.command('unstall')

    def model_params(self, **params) -> None:
        """Call ``set_params(**params)`` on the live force model."""
        self.command('model_params ' + json.dumps(params))

    def set_model(self, spec: str, **kwargs) -> None:
        """Replace the force model by ``module:factory(**kwargs)``."""
        self.command(f'model {spec} {json.dumps(kwargs)}')

    def set_pose(self, pose6: Sequence[float]) -> None:
        """Teleport the TCP (refused while it moves)."""
        self.command('set_pose ' + json.dumps([float(x) for x in pose6]))
