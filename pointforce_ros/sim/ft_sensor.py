"""Simulated tool force/torque sensor as a UR controller reports it (``actual_TCP_force``).

The reading is base-oriented, payload-compensated (the configured payload's gravity is removed;
``payload_error`` models a wrong payload setting) and zeroed by a tare. Before the tare the raw
signal is

    ``raw(t) = w_true + bias + drift_rate * t + payload_residual + noise``

and ``read`` returns ``raw(t) - offset``, where ``tare(w_true, t)`` sets ``offset`` to the
noise-free raw signal at tare time. So a tare removes the bias and the drift accumulated so far
exactly, but the drift keeps growing afterwards at ``drift_rate`` (N/s, N m/s), which is why a real
cell tares right before each poke. Noise is white, drawn per call (one call per controller tick).
Wrench vectors are ``[fx, fy, fz, tx, ty, tz]`` in N and N m, force being the force the
environment applies to the tool, torque about the TCP.
"""

from typing import Optional

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array

GRAVITY = 9.81
"""Standard gravity used for the payload residual, m/s^2 (along -z of ``base``)."""


def _vector6(value, name: str) -> np.ndarray:
    """Return a scalar or (6,) value as a (6,) float array (a scalar fills all six)."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(6, float(arr))
    return np.array(as_array(arr, name, (6,)))


class FtSensor:
    """F/T sensor with white noise, constant bias, linear drift and a tare.

    Args:
        noise_std: standard deviation of the white noise per sample, scalar or (6,)
            ``[N, N, N, N m, N m, N m]``.
        bias: constant offset of the raw signal, (6,).
        drift_rate: linear drift of the raw signal, (6,) per second (N/s, N m/s).
        payload_error: configured minus actual payload mass, kg; the compensation then leaves
            ``payload_error * g`` upward in the force (and its torque about the TCP when
            ``tcp_rotation`` is passed to ``read``).
        payload_cog: (3,) centre of gravity of the payload in the tool frame, metres.
        seed: seed of the noise generator.

    Raises:
        InvalidInput: negative noise, non-finite parameters or wrong shapes.

    """

    def __init__(self, *, noise_std=0.0, bias=0.0, drift_rate=0.0, payload_error: float = 0.0,
                 payload_cog=(0.0, 0.0, 0.0), seed: Optional[int] = None):
        self.noise_std = _vector6(noise_std, 'FtSensor.noise_std')
        if np.any(self.noise_std < 0):
            raise InvalidInput('FtSensor.noise_std: must be >= 0')
        self.bias = _vector6(bias, 'FtSensor.bias')
        self.drift_rate = _vector6(drift_rate, 'FtSensor.drift_rate')
        if not np.isfinite(payload_error):
            raise InvalidInput(f'FtSensor.payload_error: must be finite, got {payload_error}')
        self.payload_error = float(payload_error)
        self.payload_cog = np.array(as_array(payload_cog, 'FtSensor.payload_cog', (3,)))
        self._rng = np.random.default_rng(seed)
        self._noisy = bool(np.any(self.noise_std > 0))
        self.offset = np.zeros(6)
        self.tare_time: Optional[float] = None

    def _systematic(self, t: float, tcp_rotation) -> np.ndarray:
        """Raw-signal error without noise at time ``t`` (bias, drift, payload residual)."""
        out = self.bias + self.drift_rate * t
        if self.payload_error:
            force = np.array([0.0, 0.0, self.payload_error * GRAVITY])
            out[:3] += force
            if tcp_rotation is not None:
                out[3:] += np.cross(np.asarray(tcp_rotation) @ self.payload_cog, force)
        return out

    def tare(self, true_wrench6, t: float, tcp_rotation=None) -> None:
        """Zero the sensor at time ``t`` while the true wrench is ``true_wrench6`` (6,).

        Raises:
            InvalidInput: wrong shape or NaN, non-finite time.

        """
        wrench = as_array(true_wrench6, 'true_wrench6', (6,))
        if not np.isfinite(t):
            raise InvalidInput(f'FtSensor.tare: time must be finite, got {t}')
        self.offset = wrench + self._systematic(float(t), tcp_rotation)
        self.tare_time = float(t)

    def read(self, true_wrench6, t: float, tcp_rotation=None) -> np.ndarray:
        """Return the reported wrench (6,) at time ``t`` (seconds) for the true wrench (6,).

        Args:
            true_wrench6: contact wrench on the tool, base-oriented, torque about the TCP.
            t: controller time, seconds.
            tcp_rotation: (3, 3) rotation ``base <- tool`` for the payload residual torque.

        Raises:
            InvalidInput: wrong shape or NaN, non-finite time.

        """
        wrench = np.asarray(true_wrench6, dtype=np.float64)
        if wrench.shape != (6,) or not np.all(np.isfinite(wrench)) or not np.isfinite(t):
            raise InvalidInput(f'FtSensor.read: need a finite (6,) wrench and time, got shape '
                               f'{wrench.shape}, t={t}')
        out = wrench + self._systematic(float(t), tcp_rotation) - self.offset
        if self._noisy:
            out = out + self.noise_std * self._rng.standard_normal(6)
        return out
