"""Issue 18 figures: (E, nu) and camera-only contact force against the simulated cell's truth.

Reads the static pushes of ``test/data/deformation/`` (the cell's neo-Hookean FEM seen by its
depth camera; ``make_deformation_fixtures.py`` regenerates them), builds the deformation wing's
model of each object from its rest cloud, identifies (E, nu) from the pushes marked
``identify`` and estimates the force of every held-out push from its cloud alone.

Usage::

    python -m pointforce_ros.lab.deformation_figures                  # every object present
    python -m pointforce_ros.lab.deformation_figures --object foam_block --json out.json

Prints one markdown table per object (and the JSON when asked): the identified (E, nu) (and
the truth for the homogeneous object), per held-out state the true and estimated force, the
magnitude error in % of |F|, the vector error in % of |F|, the direction error in degrees, the
1-sigma magnitude uncertainty the estimate reports, and the time.
"""

import argparse
import glob
import json
import os
import time

import numpy as np

from pointforce_ros import arguments
from pointforce_ros.deformation.force import estimate_force, ForceConfig
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets
from pointforce_ros.errors import DataError, InvalidInput

FIXTURES = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', 'test', 'data',
                                        'deformation'))
"""Folder of the push fixtures."""


def _load(path):
    with np.load(path) as data:
        return dict(data)


def _cloud(push, k):
    s = push['cloud_start']
    return push['cloud'][s[k]:s[k + 1]].astype(float)


def evaluate_object(name: str, element_size: float = 0.004, layers: int = 8,
                    identify_depth: float = 0.003, corotational: bool = False,
                    folder: str = FIXTURES) -> dict:
    """Identify (E, nu) on one object's ``identify`` pushes and score its held-out pushes.

    Args:
        name: object name (``rest_<name>.npz`` and ``push_<name>_<k>.npz`` in ``folder``).
        element_size, layers: the model's mesh.
        identify_depth: depth of the states used for identification, metres.
        corotational: iterate co-rotation in the force estimates.

    Raises:
        DataError: the fixtures are missing.

    """
    rest_path = os.path.join(folder, f'rest_{name}.npz')
    paths = sorted(glob.glob(os.path.join(folder, f'push_{name}_*.npz')))
    if not os.path.isfile(rest_path) or not paths:
        raise DataError(f'no deformation fixtures for {name!r} in {folder}; run '
                        f'test/data/deformation/make_deformation_fixtures.py --object {name}')
    rest = _load(rest_path)
    pushes = [_load(p) for p in paths]
    t0 = time.perf_counter()
    mesh = volume_mesh_from_surface(rest['points'], rest['normals'], element_size=element_size,
                                    layers=layers)
    offset = rest_offsets(mesh, rest['points'])
    t_mesh = time.perf_counter() - t0
    pokes = [Poke(d['contact_point'], d['force'][k], _cloud(d, k))
             for d in pushes if str(d['role']) == 'identify'
             for k in range(len(d['depths'])) if abs(d['depths'][k] - identify_depth) < 1e-6]
    fit, fem = identify_elasticity(mesh, pokes, IdentifyConfig(), rest_offset=offset)
    rows = []
    for j, d in enumerate(pushes):
        if str(d['role']) != 'heldout':
            continue
        for k in range(len(d['depths'])):
            est = estimate_force(fem, d['contact_point'], _cloud(d, k),
                                 ForceConfig(corotational=corotational), rest_offset=offset)
            f_true = d['force'][k]
            mag = np.linalg.norm(f_true)
            cos = est.force @ f_true / (np.linalg.norm(est.force) * mag)
            rows.append(dict(
                push=j, tilt_deg=float(d['tilt_deg']), depth_mm=float(d['depths'][k] * 1e3),
                force_true=f_true.tolist(), force_est=est.force.tolist(),
                magnitude_error_pct=float(100 * (np.linalg.norm(est.force) - mag) / mag),
                vector_error_pct=float(100 * np.linalg.norm(est.force - f_true) / mag),
                direction_error_deg=float(np.degrees(np.arccos(np.clip(cos, -1, 1)))),
                sigma_magnitude=est.magnitude_std, residual_rms_mm=est.residual_rms * 1e3,
                points=est.points, seconds=est.seconds))
    vec = np.array([r['vector_error_pct'] for r in rows])
    out = dict(object=name, mesh_nodes=int(mesh.n_nodes), mesh_tets=int(len(mesh.tets)),
               element_size_m=element_size, layers=layers, mesh_seconds=t_mesh,
               identify_depth_mm=identify_depth * 1e3, identify_pokes=len(pokes),
               young=fit.young, poisson=fit.poisson,
               identify_residual_rms_mm=fit.residual_rms * 1e3,
               identify_seconds=fit.seconds, corotational=corotational, heldout=rows,
               vector_error_pct_median=float(np.median(vec)) if len(vec) else None,
               vector_error_pct_max=float(np.max(vec)) if len(vec) else None)
    # the object's base modulus: the truth of a homogeneous object, the bulk of a heterogeneous
    truth_e = float(pushes[0]['young'])
    out.update(truth_young=truth_e, truth_poisson=float(pushes[0]['poisson']),
               young_error_pct=100 * (fit.young / truth_e - 1.0),
               poisson_error=fit.poisson - float(pushes[0]['poisson']))
    return out


def table(result: dict) -> str:
    """Markdown table of one object's result."""
    r = result
    lines = [f"### {r['object']}: E = {r['young'] / 1e3:.1f} kPa, nu = {r['poisson']:.3f} "
             f"(base modulus {r['truth_young'] / 1e3:.1f} kPa, nu {r['truth_poisson']:.2f}; "
             f"{r['identify_pokes']} pokes at {r['identify_depth_mm']:.0f} mm, "
             f"{r['identify_seconds']:.2f} s; mesh {r['mesh_nodes']} nodes)", '',
             '| push | tilt | depth mm | F true N | F est N | mag err % | vec err % | dir err deg '
             '| sigma N | s |', '|' + ' --- |' * 10]
    for h in r['heldout']:
        lines.append(
            f"| {h['push']} | {h['tilt_deg']:.0f} | {h['depth_mm']:.0f} | "
            f"{np.round(h['force_true'], 2).tolist()} | {np.round(h['force_est'], 2).tolist()} | "
            f"{h['magnitude_error_pct']:+.1f} | {h['vector_error_pct']:.1f} | "
            f"{h['direction_error_deg']:.1f} | {h['sigma_magnitude']:.3f} | {h['seconds']:.3f} |")
    lines.append('')
    lines.append(f"vector error median {r['vector_error_pct_median']:.1f} %, max "
                 f"{r['vector_error_pct_max']:.1f} %")
    return '\n'.join(lines)


def main(argv=None):
    """Parse the command line, evaluate the objects, print tables (and JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--object', action='append', help='object (repeatable); default all present')
    ap.add_argument('--element-size', type=arguments.positive_float, default=0.004)
    ap.add_argument('--layers', type=arguments.positive_int, default=8)
    ap.add_argument('--identify-depth', type=arguments.positive_float, default=0.003)
    ap.add_argument('--corotational', action='store_true')
    ap.add_argument('--json', help='write the results here')
    args = ap.parse_args(argv)
    names = args.object or sorted(os.path.basename(p)[5:-4]
                                  for p in glob.glob(os.path.join(FIXTURES, 'rest_*.npz')))
    results = []
    for name in names:
        try:
            res = evaluate_object(name, args.element_size, args.layers, args.identify_depth,
                                  args.corotational)
        except InvalidInput as exc:  # a failed identification is a result, not a crash
            results.append(dict(object=name, failed=str(exc)))
            print(f'### {name}: FAILED: {exc}', flush=True)
            continue
        results.append(res)
        print(table(res), flush=True)
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(results, fh, indent=1)


if __name__ == '__main__':
    main()
