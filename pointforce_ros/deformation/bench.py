"""Benchmark of the deformation wing: one force estimate and one identification vs Nelder-Mead.

The scene is synthetic and self-contained (no simulated cell): a block on the table meshed by
:func:`.mesh.block_mesh`, pushed by the model itself at a known (E, nu) and force, and seen as
seeded points on its displaced surface with depth-like noise. Both methods get the same data
in the same run, so the ratios compare algorithms, not machines. Accuracy against the cell's
independent FEM is the lab's job (``pointforce_ros.lab.deformation_figures``).

Timings are wall clock (``time.perf_counter``, the ``*_seconds`` keys) and this process's CPU
time (``time.process_time``, the ``*_cpu_seconds`` keys): on a shared, overloaded machine the
CPU time of a single-threaded run (``OPENBLAS_NUM_THREADS=1``) is the better estimate of the
wall time on an idle one. The ratios use CPU time.
"""

import time

import numpy as np

from pointforce_ros.deformation.fem import CorotationalFem, load_columns, surface_point_load
from pointforce_ros.deformation.force import (estimate_force, estimate_force_nelder_mead,
                                              ForceConfig)
from pointforce_ros.deformation.identify import (identify_elasticity, identify_nelder_mead,
                                                 IdentifyConfig, Poke)
from pointforce_ros.deformation.mesh import block_mesh, TetMesh
from pointforce_ros.errors import InvalidInput

BLOCK = (0.08, 0.06, 0.04)
"""Size of the benchmark block, metres (the cell's foam block)."""
CORNER = (0.46, -0.03)
TRUTH = (5e4, 0.3)
"""(E Pa, nu) the synthetic pushes are made with."""


def surface_samples(mesh: TetMesh, u: np.ndarray, count: int, noise: float,
                    rng: np.random.Generator) -> np.ndarray:
    """(count, 3) area-uniform points on the displaced surface plus normal noise (std, m)."""
    x = mesh.nodes + u.reshape(-1, 3)
    c = x[mesh.surface_triangles]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    tri = rng.choice(len(c), size=count, p=area / area.sum())
    a, b = rng.uniform(size=(2, count))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    p = c[tri, 0] + a[:, None] * (c[tri, 1] - c[tri, 0]) + b[:, None] * (c[tri, 2] - c[tri, 0])
    return p + noise * rng.normal(size=(count, 1)) * n[tri] / (2 * area[tri, None])


def bench_deformation(element_size: float = 0.004, layers: int = 8, repeats: int = 5,
                      points: int = 4000, noise: float = 2e-4, baseline: bool = True,
                      identify_baseline_evaluations: int = 40, seed: int = 0) -> dict:
    """Time one force estimate and one identification, each against the paper's Nelder-Mead.

    Args:
        element_size: x-y element size of the block mesh, metres.
        layers: element layers through the 40 mm height.
        repeats: force estimates timed (the median is reported).
        points: cloud points per view.
        noise: depth noise standard deviation, metres.
        baseline: also run the Nelder-Mead baselines (slow: one co-rotational simulation per
            evaluation, and a factorisation per evaluation for the identification).
        identify_baseline_evaluations: evaluation budget of the identification baseline.
        seed: seed of the contact points, forces and noise.

    Returns:
        A JSON-ready dict: mesh size, medians in seconds, errors, the identification both
        cold (the model built inside the call) and from the model built when the surface was
        scanned (``identify_from_scan_model_*``, as the node runs it; the scan-time build is
        ``scan_model_cpu_seconds``), and the ratios
        ``force_speedup`` / ``identify_speedup`` (Nelder-Mead time / ours); ``figure`` holds
        the force speedup.

    Raises:
        InvalidInput: bad sizes or counts.

    """
    if int(repeats) < 1 or int(points) < 100 or not noise >= 0:
        raise InvalidInput('bench_deformation: need repeats >= 1, points >= 100, noise >= 0')
    rng = np.random.default_rng(seed)
    mesh = block_mesh(BLOCK, element_size, layers, grading=1.5, corner=CORNER)
    t0 = time.perf_counter()
    truth = CorotationalFem(mesh, *TRUTH)
    t_model = time.perf_counter() - t0
    top = BLOCK[2]

    def push(point, force):
        nodes, w = surface_point_load(mesh, point, 0.004)
        return truth.solve(load_columns(mesh, nodes, w) @ force)

    centre = np.array([CORNER[0] + BLOCK[0] / 2, CORNER[1] + BLOCK[1] / 2, top])
    pokes = []
    for _ in range(3):
        p = centre + np.append(rng.uniform(-0.012, 0.012, 2), 0.0)
        f = np.array([*rng.uniform(-0.2, 0.2, 2), -rng.uniform(0.8, 1.5)])
        pokes.append(Poke(p, f, surface_samples(mesh, push(p, f), points, noise, rng)))
    p_held = centre + np.append(rng.uniform(-0.012, 0.012, 2), 0.0)
    f_held = np.array([*rng.uniform(-0.3, 0.3, 2), -1.2])
    cloud = surface_samples(mesh, push(p_held, f_held), points, noise, rng)

    c0 = time.process_time()
    fit, fem = identify_elasticity(mesh, pokes)
    c_identify = time.process_time() - c0
    # as the node runs it: the object's model is built (factorised at the reference nu) when
    # its surface is scanned, so an identification starts from it
    config = IdentifyConfig()
    c0 = time.process_time()
    scanned = CorotationalFem(mesh, 5e4, config.reference_poisson)
    c_scan = time.process_time() - c0
    c0 = time.process_time()
    warm, _ = identify_elasticity(mesh, pokes, config, fem=scanned)
    c_warm = time.process_time() - c0
    out = dict(mesh_nodes=int(mesh.n_nodes), mesh_tets=int(len(mesh.tets)),
               free_dofs=int(len(fem.free)), element_size_m=float(element_size),
               model_build_seconds=t_model, identify_seconds=fit.seconds,
               identify_cpu_seconds=c_identify,
               identify_factorise_seconds=fit.factorise_seconds,
               identify_young_error=fit.young / TRUTH[0] - 1.0,
               identify_poisson_error=fit.poisson - TRUTH[1],
               identify_evaluations=fit.evaluations,
               identify_poisson_interval=list(fit.poisson_interval),
               identify_young_interval=list(fit.young_interval),
               scan_model_cpu_seconds=c_scan, identify_from_scan_model_seconds=warm.seconds,
               identify_from_scan_model_cpu_seconds=c_warm,
               identify_from_scan_model_young_error=warm.young / TRUTH[0] - 1.0,
               identify_from_scan_model_poisson_error=warm.poisson - TRUTH[1])
    config = ForceConfig()
    times, cpu, est = [], [], None
    for _ in range(int(repeats)):
        c0 = time.process_time()
        est = estimate_force(fem, p_held, cloud, config)
        cpu.append(time.process_time() - c0)
        times.append(est.seconds)
    out.update(force_seconds_median=float(np.median(times)),
               force_cpu_seconds_median=float(np.median(cpu)),
               force_error=float(np.linalg.norm(est.force - f_held) / np.linalg.norm(f_held)),
               force_std_magnitude=est.magnitude_std, force_iterations=est.iterations)
    if baseline:
        # the paper's: one co-rotational simulation per evaluation
        c0 = time.process_time()
        nm = estimate_force_nelder_mead(fem, p_held, cloud, ForceConfig(corotational=True))
        c_nm = time.process_time() - c0
        # the same optimiser on our (linear) model: what the least squares itself buys
        c0 = time.process_time()
        nml = estimate_force_nelder_mead(fem, p_held, cloud, config)
        c_nml = time.process_time() - c0
        out.update(force_nm_seconds=nm.seconds, force_nm_cpu_seconds=c_nm,
                   force_nm_evaluations=nm.iterations,
                   force_nm_error=float(np.linalg.norm(nm.force - f_held)
                                        / np.linalg.norm(f_held)),
                   force_speedup=c_nm / out['force_cpu_seconds_median'],
                   force_nm_linear_cpu_seconds=c_nml, force_nm_linear_evaluations=nml.iterations,
                   force_speedup_same_model=c_nml / out['force_cpu_seconds_median'])
        c0 = time.process_time()
        nmi = identify_nelder_mead(mesh, pokes, max_evaluations=identify_baseline_evaluations)
        c_nmi = time.process_time() - c0
        out.update(identify_nm_seconds=nmi.seconds, identify_nm_cpu_seconds=c_nmi,
                   identify_nm_evaluations=nmi.evaluations,
                   identify_nm_young_error=nmi.young / TRUTH[0] - 1.0,
                   identify_nm_poisson_error=nmi.poisson - TRUTH[1],
                   identify_speedup=c_nmi / c_identify)
        out['figure'] = out['force_speedup']
    return out
