"""Force models the emulated F/T sensor reads: the plug-in protocol and an elastic table top."""

import importlib
import math
from typing import Optional, Protocol

import numpy as np


class ForceModel(Protocol):
    """What the emulator asks of a force model (optionally also ``set_params(**kwargs)``)."""

    def wrench(self, tcp_pose6: np.ndarray, t: float) -> np.ndarray:
        """(6,) base-oriented wrench on the tool, N and N m, at TCP pose ``tcp_pose6``."""


class HalfSpaceSpring:
    """A flat elastic table top: ``F = k * penetration * n`` on the tool, zero torque.

    The surface is the plane through ``(0, 0, z0)`` with outward unit normal ``normal``
    (default +z, base frame). Penetration ``d = ((0, 0, z0) - p_tcp) . n`` when positive.
    Pushing into the table along ``-n`` therefore gives ``F . n = k d > 0``.

    Args:
        z0: height of the surface point on the z axis, m.
        k: stiffness, N/m (>= 0).
        normal: outward surface normal (3,), normalised here.
        noise_std: standard deviation of white Gaussian force noise per axis, N.
        torque_noise_std: same for torques, N m.
        seed: seed of the noise generator (``np.random.default_rng``).

    Raises:
        ValueError: negative stiffness or noise, or a zero normal.

    """

    def __init__(self, z0: float = 0.0, k: float = 1000.0, normal=(0.0, 0.0, 1.0),
                 noise_std: float = 0.0, torque_noise_std: float = 0.0, seed: int = 0):
        self._rng = np.random.default_rng(seed)
        self.z0 = 0.0
        self.k = 0.0
        self.normal = np.array([0.0, 0.0, 1.0])
        self.noise_std = 0.0
        self.torque_noise_std = 0.0
        self.set_params(z0=z0, k=k, normal=normal, noise_std=noise_std,
                        torque_noise_std=torque_noise_std)

    def set_params(self, **params) -> None:
        """Change any of ``z0``, ``k``, ``normal``, ``noise_std``, ``torque_noise_std``, ``seed``.

        Raises:
            ValueError: an unknown name or an invalid value.

        """
        for name, value in params.items():
            if name == 'seed':
                self._rng = np.random.default_rng(int(value))
            elif name == 'normal':
                n = np.asarray(value, dtype=float).reshape(3)
                norm = float(np.linalg.norm(n))
                if not np.isfinite(norm) or norm < 1e-9:
                    raise ValueError('HalfSpaceSpring.normal: must be a non-zero 3-vector')
                self.normal = n / norm
            elif name in ('z0', 'k', 'noise_std', 'torque_noise_std'):
                value = float(value)
                if not math.isfinite(value) or (name != 'z0' and value < 0.0):
                    raise ValueError(f'HalfSpaceSpring.{name}: must be finite'
                                     f'{"" if name == "z0" else " and >= 0"}, got {value}')
                setattr(self, name, value)
            else:
                raise ValueError(f'HalfSpaceSpring: unknown parameter {name!r}')

    def wrench(self, tcp_pose6: np.ndarray, t: float) -> np.ndarray:
        """(6,) base-oriented wrench on the tool at ``tcp_pose6`` (see class docstring)."""
        depth = (self.z0 * self.normal[2]) - float(np.dot(tcp_pose6[:3], self.normal))
        out = np.zeros(6)
        if depth > 0.0:
            out[:3] = self.k * depth * self.normal
        if self.noise_std > 0.0:
            out[:3] += self._rng.normal(0.0, self.noise_std, 3)
        if self.torque_noise_std > 0.0:
            out[3:] += self._rng.normal(0.0, self.torque_noise_std, 3)
        return out


def load_force_model(spec: str, kwargs: Optional[dict] = None):
    """Build a force model from ``module:factory`` and keyword arguments.

    Raises:
        ValueError: malformed spec, missing module or attribute, or an object without a
            callable ``wrench``.

    """
    if ':' not in spec:
        raise ValueError(f'force model spec {spec!r}: expected "module:factory"')
    module_name, _, attr = spec.partition(':')
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f'force model spec {spec!r}: cannot import {module_name}: {exc}')
    factory = getattr(module, attr, None)
    if factory is None:
        raise ValueError(f'force model spec {spec!r}: {module_name} has no {attr!r}')
    model = factory(**(kwargs or {}))
    if not callable(getattr(model, 'wrench', None)):
        raise ValueError(f'force model spec {spec!r}: built object has no wrench() method')
    return model
