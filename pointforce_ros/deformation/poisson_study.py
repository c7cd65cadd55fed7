"""Can Poisson's ratio be seen? Identification on the foam block with and without side pushes.

From frictionless pushes on the top seen from above, nu is nearly invisible: on a half-space
the normal surface displacement under a normal point load is ``(1 - nu^2) F / (pi E r)``, the
same shape for every nu, so a top view fixes ``(1 - nu^2) / E`` and little else (the finite,
glued block breaks this only weakly: the fit residual moved 0.8 % over nu 0.02-0.47). Oblique
pushes do not help on the cell: the contact is frictionless, so the force stays along the
surface normal (the foam block's 20 deg pushes: lateral force at most 0.33 N of 2.7 N).

A push into a *side* face does: it compresses the material near the top edge horizontally and
the top surface there rises in proportion to nu (not at all at nu = 0), a vertical motion the
camera sees. This study identifies (E, nu) with the wing's own identification
(:func:`.identify.identify_elasticity`) on sets of pushes of the homogeneous foam block (truth
E 50 kPa, nu 0.30): top pushes only (the earlier figure), side pushes only, and both; and
reports nu, its profile interval, how much the fit residual changes over nu (the
observability) and the camera-only force error each model gives on the held-out top pushes
(one normal and two 20 deg oblique, at 3, 5 and 8 mm; vector error in % of |F|). Fixtures:
``test/data/deformation/rest_foam_block.npz``, ``push_foam_block_<k>.npz`` (top) and
``side_foam_block_<k>.npz`` (side, made by ``make_side_pushes.py``).

``python -m pointforce_ros.deformation.poisson_study [--out DIR]`` prints the table (and writes
``poisson_study.json``).
"""

import argparse
import glob
import json
import os
from pathlib import Path
import sys
from typing import Dict, Sequence

import numpy as np

from pointforce_ros.deformation.identify import (_best_compliance, _loads,
                                                 identify_elasticity, IdentifyConfig, Poke,
                                                 ReducedPoissonFamily)
from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.force import estimate_force, ForceConfig
from pointforce_ros.deformation.mesh import volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets, SurfaceMatcher
from pointforce_ros.errors import DataError

FIXTURES = Path(__file__).resolve().parents[2] / 'test' / 'data' / 'deformation'
TRUTH = (5e4, 0.30)


def _load(path) -> Dict[str, np.ndarray]:
    with np.load(path) as data:
        return dict(data)


def pokes_of(push: Dict, depth: float):
    """Return the static state of a push fixture at ``depth`` (m) as an identification Poke."""
    k = int(np.argmin(np.abs(push['depths'] - depth)))
    s = push['cloud_start']
    return Poke(push['contact_point'], push['force'][k],
                push['cloud'][s[k]:s[k + 1]].astype(float))


def residual_profile(mesh, pokes, offset, config: IdentifyConfig, grid) -> np.ndarray:
    """(G,) best-E sum of squares at each nu of ``grid`` (rest pairing, linear model), m^2."""
    fem = CorotationalFem(mesh, 5e4, config.reference_poisson)
    loads = _loads(mesh, pokes, config.load_radius)
    family = ReducedPoissonFamily(fem, loads, config.krylov)
    matches = [SurfaceMatcher(mesh, p.contact_point, p.cloud, config.match,
                              rest_offset=offset).match() for p in pokes]
    corr = np.zeros_like(loads)
    return np.array([_best_compliance(matches, family.displacements(v), corr)[1]
                     for v in grid])


def heldout_errors(fem, pushes, offset) -> np.ndarray:
    """Vector force errors (% of |F|) of camera-only estimates on every state of ``pushes``."""
    out = []
    for push in pushes:
        for depth in push['depths']:
            poke = pokes_of(push, float(depth))
            est = estimate_force(fem, poke.contact_point, poke.cloud, ForceConfig(),
                                 rest_offset=offset)
            out.append(100 * np.linalg.norm(est.force - poke.force) / np.linalg.norm(poke.force))
    return np.array(out)


def study(folder=FIXTURES, element_size: float = 0.004, depths: Sequence[float] = (0.003, 0.005)
          ) -> Dict:
    """Identify on the top-only, side-only and combined sets; return rows per set and depth.

    Raises:
        DataError: the fixtures are missing (the message names the script that makes them).

    """
    folder = Path(folder)
    rest_path = folder / 'rest_foam_block.npz'
    top = [_load(p) for p in sorted(glob.glob(str(folder / 'push_foam_block_*.npz')))]
    side = [_load(p) for p in sorted(glob.glob(str(folder / 'side_foam_block_*.npz')))]
    if not rest_path.is_file() or not top:
        raise DataError(f'no foam_block fixtures in {folder}: run '
                        'test/data/deformation/make_deformation_fixtures.py --object foam_block')
    if not side:
        raise DataError(f'no side pushes in {folder}: run '
                        'test/data/deformation/make_side_pushes.py')
    rest = _load(rest_path)
    mesh = volume_mesh_from_surface(rest['points'], rest['normals'], element_size=element_size,
                                    layers=8)
    offset = rest_offsets(mesh, rest['points'])
    config = IdentifyConfig()
    top_id = [p for p in top if str(p['role']) == 'identify']
    heldout = [p for p in top if str(p['role']) == 'heldout']
    grid = np.linspace(0.02, 0.47, 10)
    rows = []
    for depth in depths:
        sets = {'top (3 normal pushes)': [pokes_of(p, depth) for p in top_id],
                'side (2 pushes)': [pokes_of(p, depth) for p in side],
                'top + side': [pokes_of(p, depth) for p in top_id + side]}
        for name, pokes in sets.items():
            fit, fem = identify_elasticity(mesh, pokes, config, rest_offset=offset)
            errors = heldout_errors(fem, heldout, offset)
            sse = residual_profile(mesh, pokes, offset, config, grid)
            rows.append({'set': name, 'depth_mm': 1e3 * depth, 'pokes': len(pokes),
                         'young': fit.young, 'poisson': fit.poisson,
                         'young_error_pct': 100 * (fit.young / TRUTH[0] - 1),
                         'poisson_error': fit.poisson - TRUTH[1],
                         'poisson_interval': list(fit.poisson_interval),
                         'residual_rms_mm': 1e3 * fit.residual_rms,
                         'residual_change_pct': float(100 * (sse.max() / sse.min() - 1)),
                         'heldout_force_error_pct_median': float(np.median(errors)),
                         'heldout_force_error_pct_max': float(np.max(errors)),
                         'profile_nu': grid.tolist(), 'profile_sse': sse.tolist(),
                         'seconds': fit.seconds})
    return {'rows': rows, 'truth': {'young': TRUTH[0], 'poisson': TRUTH[1]},
            'mesh': {'nodes': int(mesh.n_nodes), 'element_size': element_size}}


def table(result: Dict) -> str:
    """Markdown table of the study."""
    lines = ['| set | depth mm | E kPa (err) | nu (err) | nu interval | residual change over nu'
             ' 0.02-0.47 | held-out force error median / max |', '|' + ' --- |' * 7]
    for r in result['rows']:
        lo, hi = r['poisson_interval']
        lines.append(f'| {r["set"]} | {r["depth_mm"]:.0f} | {r["young"] / 1e3:.1f} '
                     f'({r["young_error_pct"]:+.1f} %) | {r["poisson"]:.3f} '
                     f'({r["poisson_error"]:+.3f}) | {lo:.3f}-{hi:.3f} | '
                     f'{r["residual_change_pct"]:.1f} % | '
                     f'{r.get("heldout_force_error_pct_median", float("nan")):.1f} / '
                     f'{r.get("heldout_force_error_pct_max", float("nan")):.1f} % |')
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Command line: ``python -m pointforce_ros.deformation.poisson_study [--out DIR]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', help='folder for poisson_study.json')
    ap.add_argument('--element-size', type=float, default=0.004)
    args = ap.parse_args(argv)
    result = study(element_size=args.element_size)
    print(table(result))
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, 'poisson_study.json'), 'w') as fh:
            json.dump(result, fh, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
