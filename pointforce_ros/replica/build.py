"""``pointforce replica``: calibrate a PyBullet replica to measured pokes and write it.

Steps: read the pokes and the scanned surface (:func:`pointforce_ros.replica.data.load_pokes`);
mesh the body from the scan at a fixed, recorded resolution; split the pokes into training and
held-out (seeded); run both calibrators on the training pokes (the paper's MLP and our scaling
fit), each followed by the damping step gated on the held-out pokes; score both on the held-out
pokes; write the replica of the calibrator with the lower held-out curve error, with every
figure of both in ``replica.json``.
"""

from pathlib import Path
import time
from typing import Callable, Dict

from pointforce_ros.errors import InvalidInput
from pointforce_ros.replica.calibrate import (calibrate_paper, calibrate_scaling,
                                              damping_step, evaluate, summary)
from pointforce_ros.replica.data import load_pokes, subset
from pointforce_ros.replica.mesh import heightfield_tet_mesh
from pointforce_ros.replica.replica import write_replica
from pointforce_ros.replica.scene import SceneConfig

ENGINES = ('pybullet',)


def build_replica(data, out, *, engine: str = 'pybullet', h: float = 0.01, train: int = 3,
                  held_out: int = 3, damping: bool = True, seed: int = 0, thin: int = 5,
                  say: Callable[[str], None] = print) -> Dict:
    """Calibrate and write a replica; return the figures written to ``replica.json``.

    Args:
        data: poke store, generated data set directory, or poke fixture ``.npz``.
        out: replica directory.
        engine: only ``pybullet``.
        h: mesh edge length, metres (recorded; the replica's response depends on it).
        train, held_out: pokes used for calibration and for the held-out figures.
        damping: run the damping step.
        seed: split seed.
        thin: keep every ``thin``-th measured sample (the error is per curve).
        say: progress printer.

    Raises:
        InvalidInput: unknown engine, bad counts, no pokes.
        DataError: unreadable data or no surface.

    """
    if engine not in ENGINES:
        raise InvalidInput(f'--engine: {engine!r} is not supported; use one of {ENGINES}')
    if train < 1 or held_out < 1:
        raise InvalidInput(f'--train and --held-out must be >= 1, got {train}, {held_out}')
    started = time.monotonic()
    pokes = load_pokes(data)
    fit_set, test_set = pokes.split(held_out / (train + held_out), seed=seed)
    fit_set, test_set = subset(fit_set[:train], thin), subset(test_set[:held_out], thin)
    mesh = heightfield_tet_mesh(pokes.surface_points, h, surface_normals=pokes.surface_normals)
    config = SceneConfig()
    say(f'[replica] {len(pokes.pokes)} pokes ({len(fit_set)} train, {len(test_set)} held '
        f'out); mesh {h * 1e3:g} mm: {len(mesh.nodes)} nodes, {len(mesh.tets)} tets')
    figures: Dict = {'data': str(data), 'train': [p.poke_id for p in fit_set],
                     'held_out': [p.poke_id for p in test_set]}
    calibs = {}
    for run in (calibrate_scaling, calibrate_paper):
        calib = run(mesh, fit_set, config, say=say)
        static_errors = summary(evaluate(mesh, calib.static, test_set, config))
        if damping:
            calib = damping_step(mesh, calib, fit_set, test_set, config, say=say)
            if calib.damping_accepted and calib.name == 'paper':
                # the paper's third step: (lambda, mu) again on a grid at the new damping
                again = calibrate_paper(mesh, fit_set, config, damping=calib.final.damping,
                                        say=say)
                calib.final = again.final
                calib.simulations += again.simulations
                calib.seconds += again.seconds
        final_errors = (summary(evaluate(mesh, calib.final, test_set, config))
                        if calib.damping_accepted else static_errors)
        figures[calib.name] = {'held_out_static': static_errors,
                               'held_out_final': final_errors,
                               'simulations': calib.simulations, 'seconds': calib.seconds}
        calibs[calib.name] = calib
        say(f'[replica] {calib.name}: held-out {final_errors}, {calib.simulations} '
            f'simulations, {calib.seconds:.0f} s')
    best = min(calibs, key=lambda k: figures[k]['held_out_final']['curve_pct'])
    figures['chosen'] = best
    figures['seconds'] = time.monotonic() - started
    write_replica(Path(out), mesh, calibs[best].final, config, figures=figures,
                  calibrations={k: c.to_json() for k, c in calibs.items()})
    say(f'[replica] wrote {out} ({best} calibrator) in {figures["seconds"]:.0f} s')
    return figures
