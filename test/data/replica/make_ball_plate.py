"""Generate the plate-on-ball truth curves of the replica (seed 002), independent of PyBullet.

A 90 mm foam ball lies on a rigid table and a flat plate compresses it up to 30 mm. The truth
comes from the cell's own ground-truth FEM (:mod:`pointforce_ros.sim.fem`: neo-Hookean large
deformation, hexahedra, frictionless augmented-Lagrangian contact with a rigid triangle-mesh
probe, Newton with line search), not from the engine being calibrated:

* Symmetry: with frictionless plate and table the ball deforms symmetrically about its
  mid-plane, so the model is the upper hemisphere with its equatorial plane sliding (``z``
  fixed) and the plate travels half the compression; the force is the whole ball's.
* Mesh: a half cube ``[-1, 1]^2 x [0, 1]`` of hexahedra mapped onto the hemisphere by the
  cube-to-ball map (the bottom face onto the equatorial disk).
* Plate: :func:`pointforce_ros.sim.fem.probes.box_probe`, 150 x 150 mm, rounded 4 mm edges.
* Material: relaxed (long-term) Young's modulus ``YOUNG`` and Poisson ratio ``POISSON``.
* Rate dependence (declared, for the damping step to find): quasi-linear viscoelasticity with
  one Prony term, ``F(t) = F_inf(d(t)) + PRONY_G * int_0^t exp(-(t - s) / PRONY_TAU)
  dF_inf(d(s))``: the FEM force is the relaxed response, faster pushes overshoot it and the
  force relaxes back towards it while the plate holds.
* Trials: ramp at ``SPEEDS`` (m/s) from contact to ``MAX_COMPRESSION``, hold ``HOLD`` s,
  sampled at 250 Hz, with seeded Gaussian F/T noise ``NOISE`` N. Each trial also carries its
  static curve: the relaxed force at ``STATIC_DEPTHS`` (what a staircase relaxation test
  reads at the end of each hold) with its own noise. Roles: ``TRAIN`` and the rest held out.
* Section (for the contour check): ``section_xz``, the deformed outline of the ball in the
  plane ``y = 0`` at ``MAX_COMPRESSION`` (the held-out trials' largest compression), (S, 2)
  points ``(x, z)`` in the table frame, ordered by angle about the deformed centre.

Regenerate (about 2 minutes per mesh on the 2-core machine)::

    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python test/data/replica/make_ball_plate.py

writes ``ball_plate.npz`` beside this script (and prints the coarse/fine FEM comparison).
``--core-young 150e3 --core-radius 0.025 --out .../ball_core.npz`` makes a heterogeneous ball
(a stiff core in the soft ball: what one homogeneous replica can and cannot reach).
"""

import argparse
from dataclasses import replace
from pathlib import Path
import sys
import time

import numpy as np

from pointforce_ros.sim.fem.mesh import replace_nodes, structured_hex
from pointforce_ros.sim.fem.probes import box_probe, pose_for_push
from pointforce_ros.sim.fem.solver import FemModel

RADIUS = 0.045
"""Ball radius, m (seed 002: 90 mm foam balls)."""
MAX_COMPRESSION = 0.030
"""Largest plate travel past contact, m (the whole ball's compression)."""
YOUNG = 5.0e4
"""Relaxed Young's modulus, Pa."""
POISSON = 0.3
"""Poisson ratio."""
PRONY_G = 0.4
"""Prony weight of the rate-dependent force (relative to the relaxed one)."""
PRONY_TAU = 0.8
"""Prony relaxation time, s."""
SPEEDS = (0.010, 0.012, 0.015, 0.018, 0.020, 0.025, 0.030, 0.040)
"""Plate speed of each trial, m/s."""
TRAIN = (0, 3, 6)
"""Indices of the training trials (10, 18 and 30 mm/s); the other five are held out."""
HOLD = 1.5
"""Hold after the push, s."""
RATE = 250.0
"""Sampling rate, Hz."""
NOISE = 0.02
"""F/T noise standard deviation, N."""
STATIC_DEPTHS = np.linspace(0.002, MAX_COMPRESSION, 15)
"""Depths of the static (relaxed) curve, m."""
SEED = 19


def hemisphere_mesh(radius: float, n: int, layers: int):
    """Hexahedral mesh of the upper hemisphere (equator on ``z = 0``); ``n`` elements across."""
    cube = structured_hex(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1),
                          np.linspace(0, 1, layers + 1))
    u, v, w = cube.nodes.T
    x = u * np.sqrt(1 - v * v / 2 - w * w / 2 + v * v * w * w / 3)
    y = v * np.sqrt(1 - u * u / 2 - w * w / 2 + u * u * w * w / 3)
    z = w * np.sqrt(1 - u * u / 2 - v * v / 2 + u * u * v * v / 3)
    return replace_nodes(cube, radius * np.column_stack([x, y, z]))


def indent_ball(n: int, layers: int, steps: int, core_young: float = 0.0,
                core_radius: float = 0.0):
    """Press the plate into the hemisphere to ``MAX_COMPRESSION``; return ``(mesh, result)``.

    ``core_young`` > 0: the elements whose centroid lies within ``core_radius`` (m) of the
    centre have that Young's modulus (Pa). Every node is reported at every step.
    """
    mesh = hemisphere_mesh(RADIUS, n, layers)
    young = np.full(len(mesh.elements), YOUNG)
    if core_young > 0:
        young[np.linalg.norm(mesh.centroids(), axis=1) < core_radius] = core_young
    # every node reported at every step (the solver reports ``top_nodes``; nothing else
    # reads them), so that the section can be taken from the sides as well as the cap
    everything = replace(mesh, top_nodes=np.arange(mesh.n_nodes)[:, None])
    model = FemModel(everything, young, POISSON, support='sliding')
    plate = box_probe((0.15, 0.15, 0.02), edge_radius=0.004)
    half = np.linspace(0.5, steps, steps) / steps * (MAX_COMPRESSION / 2)
    start = pose_for_push([0.0, 0.0, RADIUS], [0.0, 0.0, -1.0])
    return mesh, model.indent(plate, start, [0.0, 0.0, -1.0], half)


def relaxed_curve(n: int, layers: int, steps: int = 30, core_young: float = 0.0,
                  core_radius: float = 0.0):
    """Return the FEM's plate travel (K,) m and relaxed force (K,) N (whole ball), and section.

    The section is the ball's deformed outline in the plane ``y = 0`` at the largest
    compression, (S, 2) points ``(x, z)``, metres, table frame (table at ``z = 0``), ordered
    by angle about the deformed centre ``(0, RADIUS - MAX_COMPRESSION / 2)``: the hemisphere's
    surface nodes of that plane and their mirror images below the mid-plane.

    With ``core_young`` > 0 the elements whose centroid lies within ``core_radius`` (m) of
    the ball's centre have that Young's modulus (Pa): a heterogeneous ball, stiff or soft
    inside.
    """
    mesh, res = indent_ball(n, layers, steps, core_young, core_radius)
    rest = mesh.nodes
    on_plane = (np.abs(rest[:, 1]) < 1e-9) & (np.abs(np.linalg.norm(rest, axis=1) - RADIUS)
                                              < 1e-9)
    upper = res.surface[-1][on_plane][:, [0, 2]]
    mid = RADIUS - MAX_COMPRESSION / 2
    section = np.concatenate([upper, upper[upper[:, 1] > 1e-9] * [1.0, -1.0]])
    section[:, 1] += mid
    section = section[np.argsort(np.arctan2(section[:, 1] - mid, section[:, 0]))]
    return (np.concatenate([[0.0], 2 * res.depths]), np.concatenate([[0.0], res.force[:, 2]]),
            section)


def prony_force(t: np.ndarray, f_relaxed: np.ndarray) -> np.ndarray:
    """Quasi-linear viscoelastic force of the relaxed history ``f_relaxed`` (T,) at ``t`` (T,)."""
    out = np.empty_like(f_relaxed)
    state = 0.0
    out[0] = f_relaxed[0]
    for k in range(1, len(t)):
        dt = t[k] - t[k - 1]
        decay = np.exp(-dt / PRONY_TAU)
        # dF spread evenly over the interval: int exp(-(t_k - s)/tau) ds / dt, exactly
        state = (state * decay
                 + PRONY_G * (f_relaxed[k] - f_relaxed[k - 1]) * (1 - decay) * PRONY_TAU / dt)
        out[k] = f_relaxed[k] + state
    return out


def trials(depth_fem: np.ndarray, force_fem: np.ndarray, rng) -> dict:
    """Ramp-and-hold trials and their static curves, flattened with offsets."""
    def relaxed(d):
        return np.interp(d, depth_fem, force_fem)
    out = {k: [] for k in ('t', 'depth', 'force', 'static_depth', 'static_force')}
    for v in SPEEDS:
        t_push = MAX_COMPRESSION / v
        t = np.arange(0.0, t_push + HOLD + 1e-9, 1.0 / RATE)
        d = np.minimum(t * v, MAX_COMPRESSION)
        f = prony_force(t, relaxed(d)) + rng.normal(0.0, NOISE, len(t))
        out['t'].append(t)
        out['depth'].append(d)
        out['force'].append(f)
        out['static_depth'].append(STATIC_DEPTHS)
        out['static_force'].append(relaxed(STATIC_DEPTHS)
                                   + rng.normal(0.0, NOISE, len(STATIC_DEPTHS)))
    return out


def main(argv=None) -> int:
    """Solve the FEM at two meshes, write the fixture from the fine one."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--n', type=int, default=16, help='elements across the fine mesh')
    ap.add_argument('--n-coarse', type=int, default=12, help='elements across the coarse mesh')
    ap.add_argument('--out', default=str(Path(__file__).with_name('ball_plate.npz')))
    ap.add_argument('--core-young', type=float, default=0.0,
                    help="Young's modulus of a core (Pa; 0: homogeneous ball)")
    ap.add_argument('--core-radius', type=float, default=0.025, help='core radius, m')
    args = ap.parse_args(argv)
    curves = {}
    for n in (args.n_coarse, args.n):
        started = time.monotonic()
        curves[n] = relaxed_curve(n, n // 2, core_young=args.core_young,
                                  core_radius=args.core_radius)
        print(f'FEM n={n}: F(30 mm) = {curves[n][1][-1]:.3f} N in '
              f'{time.monotonic() - started:.0f} s', flush=True)
    depth, force, section = curves[args.n]
    coarse = np.interp(depth, *curves[args.n_coarse][:2])
    change = float(np.max(np.abs(coarse[1:] / force[1:] - 1)))
    print(f'coarse -> fine FEM: largest force change {100 * change:.2f} %')
    rng = np.random.default_rng(SEED)
    data = trials(depth, force, rng)
    flat = {k: np.concatenate(v) for k, v in data.items()}
    core = ({'core_young': args.core_young, 'core_radius': args.core_radius}
            if args.core_young > 0 else {})
    role = np.array(['train' if k in TRAIN else 'heldout' for k in range(len(SPEEDS))])
    np.savez_compressed(
        args.out, fem_depth=depth, fem_force=force, fem_force_coarse=coarse,
        offsets=np.cumsum([0] + [len(t) for t in data['t']]),
        static_offsets=np.cumsum([0] + [len(d) for d in data['static_depth']]),
        speeds=np.array(SPEEDS), role=role, radius=RADIUS, hold=HOLD,
        young=YOUNG, poisson=POISSON, prony_g=PRONY_G, prony_tau=PRONY_TAU, noise=NOISE,
        section_xz=section, section_depth=MAX_COMPRESSION, **core, **flat)
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
