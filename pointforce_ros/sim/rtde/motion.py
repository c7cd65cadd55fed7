"""Kinematics of the emulated TCP: trapezoidal linear moves, stops, speed moves."""

import math
from typing import Callable, Sequence

import numpy as np

from pointforce_ros.rotations import matrix_to_rotvec, rotvec_to_matrix


class Kinematics:
    """TCP state: position p (3,), rotation matrix r (3, 3), linear v (3,) and angular w (3,)."""

    def __init__(self, pose6: Sequence[float]):
        self.p = np.array(pose6[:3], dtype=float)
        self.r = rotvec_to_matrix(pose6[3:6])
        self.v = np.zeros(3)
        self.w = np.zeros(3)
        self._rotvec_of = (None, None)

    def pose6(self) -> np.ndarray:
        """Return the TCP pose [x, y, z, rx, ry, rz] (m, rad, base)."""
        rot, rotvec = self._rotvec_of
        if rot is not self.r:   # a TCP at rest keeps its matrix: convert it once (~100 us)
            rot, rotvec = self.r, matrix_to_rotvec(self.r)
            self._rotvec_of = (rot, rotvec)
        return np.concatenate([self.p, rotvec])

    def twist6(self) -> np.ndarray:
        """Return the TCP twist [vx, vy, vz, wx, wy, wz] (m/s, rad/s, base)."""
        return np.concatenate([self.v, self.w])

    def integrate(self, v_new: np.ndarray, w_new: np.ndarray, dt: float) -> None:
        """Advance the pose by ``dt`` seconds to the new twist (trapezoidal rule)."""
        self.p = self.p + 0.5 * (self.v + v_new) * dt
        self.r = rotvec_to_matrix(0.5 * (self.w + w_new) * dt) @ self.r
        self.v = v_new
        self.w = w_new


class Trapezoid:
    """Rest-to-rest trapezoidal profile over ``length`` with speed and acceleration limits."""

    def __init__(self, length: float, speed: float, accel: float):
        self.length = length
        self.a = accel
        if length <= 0.0:
            self.ta, self.tf, self.vp = 0.0, 0.0, 0.0
        elif length >= speed * speed / accel:
            self.ta, self.vp = speed / accel, speed
            self.tf = (length - speed * speed / accel) / speed
        else:
            self.vp = math.sqrt(length * accel)
            self.ta, self.tf = self.vp / accel, 0.0
        self.duration = 2.0 * self.ta + self.tf

    def at(self, t: float):
        """Return (distance, speed) along the profile at time ``t`` seconds after its start."""
        if t <= 0.0:
            return 0.0, 0.0
        if t < self.ta:
            return 0.5 * self.a * t * t, self.a * t
        if t < self.ta + self.tf:
            return 0.5 * self.a * self.ta ** 2 + self.vp * (t - self.ta), self.vp
        if t < self.duration:
            rest = self.duration - t
            return self.length - 0.5 * self.a * rest * rest, self.a * rest
        return self.length, 0.0


class LinearMove:
    """moveL: straight line in position, geodesic in orientation, trapezoidal in time."""

    def __init__(self, kin: Kinematics, target6: Sequence[float], speed: float, accel: float):
        self.p0, self.r0 = kin.p.copy(), kin.r.copy()
        self.p1 = np.array(target6[:3], dtype=float)
        self.r1 = rotvec_to_matrix(target6[3:6])
        self.dp = self.p1 - self.p0
        self.rel = matrix_to_rotvec(self.r0.T @ self.r1)
        dist = float(np.linalg.norm(self.dp))
        length = dist if dist > 1e-7 else float(np.linalg.norm(self.rel))
        self.profile = Trapezoid(length, speed, accel)
        self.t = 0.0
        self.target = np.array(target6, dtype=float)

    def step(self, kin: Kinematics, dt: float) -> bool:
        """Advance the motion by one controller period; return whether it has finished."""
        self.t += dt
        if self.t >= self.profile.duration:
            kin.p, kin.r = self.p1.copy(), self.r1.copy()
            kin.v, kin.w = np.zeros(3), np.zeros(3)
            return True
        s, sd = self.profile.at(self.t)
        frac, rate = s / self.profile.length, sd / self.profile.length
        kin.p = self.p0 + self.dp * frac
        kin.r = self.r0 @ rotvec_to_matrix(self.rel * frac)
        kin.v = self.dp * rate
        kin.w = self.r0 @ self.rel * rate
        return False


class StopMove:
    """stopl: decelerate the current twist along its direction at ``decel`` until at rest."""

    def __init__(self, decel: float):
        self.decel = decel

    def step(self, kin: Kinematics, dt: float) -> bool:
        """Advance the motion by one controller period; return whether it has finished."""
        speed = float(np.linalg.norm(kin.v))
        ang = float(np.linalg.norm(kin.w))
        ref = speed if speed > 1e-12 else ang
        if ref <= 1e-12:
            kin.v, kin.w = np.zeros(3), np.zeros(3)
            return True
        ratio = max(ref - self.decel * dt, 0.0) / ref
        kin.integrate(kin.v * ratio, kin.w * ratio, dt)
        return ratio == 0.0


class SpeedMove:
    """speedl: approach the target twist with bounded acceleration and hold it."""

    def __init__(self, twist6: Sequence[float], accel: float):
        self.target = np.array(twist6, dtype=float)
        self.accel = accel

    def step(self, kin: Kinematics, dt: float) -> bool:
        """Advance the motion by one controller period; return whether it has finished."""
        def approach(cur, want):
            delta = want - cur
            norm = float(np.linalg.norm(delta))
            limit = self.accel * dt
            return want.copy() if norm <= limit else cur + delta * (limit / norm)
        kin.integrate(approach(kin.v, self.target[:3]), approach(kin.w, self.target[3:]), dt)
        return False


class MoveSequence:
    """Run motions one after the other; each factory builds its motion from the state then."""

    def __init__(self, *factories: Callable[[Kinematics], object]):
        self.factories = list(factories)
        self.current = None

    def step(self, kin: Kinematics, dt: float) -> bool:
        """Advance the motion by one controller period; return whether it has finished."""
        while True:
            if self.current is None:
                if not self.factories:
                    return True
                self.current = self.factories.pop(0)(kin)
            if not self.current.step(kin, dt):
                return False
            self.current = None
            if not self.factories:
                return True


class Ring:
    """Fixed-size history of (ticks, width) float rows, newest last."""

    def __init__(self, size: int, width: int):
        self.data = np.zeros((size, width))
        self.count = 0

    def push(self, row: np.ndarray) -> None:
        """Append one row, overwriting the oldest when full."""
        self.data[self.count % len(self.data)] = row
        self.count += 1

    def last(self, n: int) -> np.ndarray:
        """Return the newest ``n`` rows (fewer if fewer were pushed), oldest first."""
        n = min(n, self.count, len(self.data))
        idx = (np.arange(self.count - n, self.count)) % len(self.data)
        return self.data[idx]
