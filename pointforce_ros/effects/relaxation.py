"""Prony-series relaxation as linear filters of a uniformly sampled force (pure, no ROS).

The viscoelastic effect of :mod:`pointforce_ros.effects.library` relaxes the elastic force
``f_e`` into ``f = g_inf f_e + sum_i g_i h_i``, ``h_i`` the hereditary integral with relaxation
time ``tau_i`` (weights and times from :func:`~pointforce_ros.effects.library.prony_terms`):

* :func:`hereditary`: one term, a stable first-order recursion (exact for a force piecewise
  linear in time).
* :func:`prony_filter` / :func:`prony_inverse`: the whole series and its inverse (the
  corrections of :mod:`pointforce_ros.effects.correct` and the diagnosis model use them).

Kept apart from the effect library so that the contact service, which needs the library's
parameters but never filters a series, does not load ``scipy.signal`` (about half of its
start-up time).
"""

from typing import Tuple

import numpy as np
from scipy.signal import lfilter


def _prony_coefficients(dt: float, g, tau):
    """Numerator and denominator (in ``z^-1``) of the Prony filter ``f_e -> f`` (the inverse)."""
    g = np.atleast_1d(np.asarray(g, dtype=np.float64))
    tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    a, r = _prony_step(dt, tau)
    g_inf = 1.0 - float(g.sum())
    den = np.array([1.0])
    for ai in a:
        den = np.polymul(den, [1.0, -ai])
    num = g_inf * den
    for i in range(len(g)):
        term = np.array([g[i] * r[i], -g[i] * r[i]])
        for j, aj in enumerate(a):
            if j != i:
                term = np.polymul(term, [1.0, -aj])
        num = num + term  # both have K + 1 coefficients in powers of z^-1
    return num, den


def _prony_step(dt: float, tau) -> Tuple[np.ndarray, np.ndarray]:
    """Per-sample decay ``exp(-dt / tau)`` and ramp weight ``(1 - exp(-x)) / x``, x = dt / tau.

    Both lie in [0, 1] for any ``dt >= 0`` and ``tau > 0`` (no overflow: the exponent is never
    positive; ``tau`` from milliseconds to hours).
    """
    tau = np.maximum(np.atleast_1d(np.asarray(tau, dtype=np.float64)), 1e-12)
    ratio = max(float(dt), 0.0) / tau
    a = np.exp(-ratio)
    r = np.where(ratio > 1e-8, -np.expm1(-ratio) / np.maximum(ratio, 1e-300), 1.0 - 0.5 * ratio)
    return a, r


def hereditary(f_e: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """Return the hereditary integral ``h(t) = int exp(-(t - s) / tau) df_e(s)`` (at rest before).

    The stable first-order recursion ``h_n = a h_{n-1} + r (f_n - f_{n-1})`` with ``a`` and
    ``r`` of :func:`_prony_step` (both in [0, 1]: bounded for bounded input, whatever ``tau``).
    Exact for ``f_e`` piecewise linear in time.

    Args:
        f_e: (T,) or (T, k) uniformly sampled series, along axis 0.
        dt: sample spacing, seconds.
        tau: relaxation time, seconds, > 0.

    """
    a, r = _prony_step(dt, tau)
    f_e = np.asarray(f_e, dtype=np.float64)
    return lfilter([float(r[0]), -float(r[0])], [1.0, -float(a[0])], f_e, axis=0)


def prony_filter(f_e: np.ndarray, dt: float, g, tau) -> np.ndarray:
    """Relax an elastic force series: ``f = g_inf f_e + sum_i g_i h_i`` (material at rest before).

    ``h_i`` is the hereditary integral ``int exp(-(t - s) / tau_i) df_e(s)`` (:func:`hereditary`:
    one stable first-order recursion per term, summed, instead of one high-order polynomial
    filter whose coefficients lose precision when relaxation times span decades).

    Args:
        f_e: (T,) or (T, k) elastic force, uniformly sampled, newtons.
        dt: sample spacing, seconds.
        g: relaxing fractions (K,), sum < 1.
        tau: relaxation times (K,), seconds.

    Returns:
        Array shaped like ``f_e`` (not clamped).

    """
    g = np.atleast_1d(np.asarray(g, dtype=np.float64))
    tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    f_e = np.asarray(f_e, dtype=np.float64)
    out = (1.0 - float(g.sum())) * f_e
    for gi, ti in zip(g, tau):
        if gi != 0.0:
            out = out + gi * hereditary(f_e, dt, ti)
    return out


def prony_inverse(f: np.ndarray, dt: float, g, tau) -> np.ndarray:
    """Invert :func:`prony_filter`: the elastic force whose relaxed response is ``f``."""
    num, den = _prony_coefficients(dt, g, tau)
    return lfilter(den, num, f, axis=0)
