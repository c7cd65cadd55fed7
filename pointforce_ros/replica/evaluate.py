"""Lab script: a written replica's held-out figures, contour error and resolution sensitivity.

Usage (after ``pointforce replica ... --out DIR``)::

    nice .venv/bin/python -m pointforce_ros.replica.evaluate DIR --h-fine 0.0075 \
        [--clouds 'test/data/deformation/push_foam_block_*.npz']

Prints one JSON object (also written to ``DIR/evaluation.json``):

* ``figures``: the figures ``replica.json`` reported, per calibrator (held-out steady-force
  errors at the largest compression and over the curve, before/after the damping step,
  simulations, wall time);
* ``reproduced``: the chosen replica's held-out errors recomputed from the files;
* ``phases`` (with ``--phases``): the force-time residual by phase on ramp-and-hold pokes;
* ``resolution``: the force of the replica's material at the deepest point of each held-out
  poke at the replica's mesh and at ``--h-fine`` (how far a replica moves with resolution);
* ``contour``: with ``--clouds`` (push files that hold the camera cloud under load), the
  replica's top along the section through the probe against the camera's, % of the width;
* ``camera_section``: where ``<data stem>_camera.npz`` lies beside the data (or ``--camera``:
  the cell's camera's views of the loaded truth, ``test/data/replica/make_ball_camera.py``),
  the replica's section against the camera's and the truth's against the camera's (the
  camera's own floor), raw and with each camera's depth bias removed on its rest frames
  (:func:`pointforce_ros.replica.contour.ball_camera_figures`);
* ``residual_map`` (with ``--map``): the held-out residual by depth, time, site and section
  angle (:mod:`pointforce_ros.replica.residual_map`), drawn into ``DIR/residual_map.png``;
* ``section``: where the data file holds the truth's deformed section (``section_xz`` of the
  plate-on-ball fixture), the replica's section at the same compression against it, % of
  the section's width (:func:`pointforce_ros.replica.contour.ball_section_error`).
"""

import argparse
import glob
import json
from pathlib import Path
import sys
import time
from typing import Optional

import numpy as np

from pointforce_ros.replica.build import replica_body
from pointforce_ros.replica.calibrate import (evaluate, force_at, force_time_summary,
                                              simulate_loading, simulate_series, summary)
from pointforce_ros.replica.contour import (ball_camera_figures, ball_section,
                                            camera_section, contour_error, read_camera_views,
                                            remove_depth_bias, section_error)
from pointforce_ros.replica.data import load_pokes, subset
from pointforce_ros.replica.mesh import read_vtk
from pointforce_ros.replica.replica import read_description
from pointforce_ros.replica.residual_map import plot_residual_map, residual_map
from pointforce_ros.replica.scene import Material, SceneConfig


def held_out_figures(mesh, material, config, data, section=None, camera=None) -> dict:
    """Figures of a replica on the held-out trials of ``data`` (a :class:`PokeSet`).

    The static force errors at the largest compression and over the curve on every held-out
    poke, and, where the pokes carry a ramp-and-hold ``series``, the force-time error of the
    fastest held-out one (the shortest simulation). Percent, newtons. With ``section``
    (``(compression, section_xz)`` of :func:`truth_section`) also the section's errors
    against the truth's (:func:`pointforce_ros.replica.contour.section_error`) as
    ``section_<key>``, and with ``camera`` (:func:`pointforce_ros.replica.contour.
    read_camera_views`) against the camera's, its depth bias removed on the rest frames, as
    ``camera_<key>`` (:func:`pointforce_ros.replica.contour.ball_camera_figures`).
    """
    _, held = data.split()
    out = summary(evaluate(mesh, material, held, config))
    timed = [p for p in held if p.series is not None]
    if timed:
        fastest = max(timed, key=lambda p: p.speed)
        out.update(force_time_summary(mesh, material, [fastest], config))
        out['force_time_poke'] = fastest.poke_id
    if section is not None:
        outline, centre, actual = ball_section(mesh, material, config, section[0])
        errors = dict(section_error(section[1], outline, centre), compression_m=actual)
        out.update({f'section_{k}': v for k, v in errors.items()})
        if camera is not None:
            cam = ball_camera_figures(camera, outline, section[1], centre)
            out.update({f'camera_{k}': v for k, v in cam['rest_corrected']['replica'].items()})
    return out


def phase_residuals(mesh, material, pokes, config) -> dict:
    """Force-time residual of ramp-and-hold pokes by phase: what the damping step can see.

    Per poke: RMS of (replica - measured) force while the pusher moves and while it holds,
    the mean signed residual of each phase, and the relaxation over the hold (force in its
    first 0.1 s minus its last 0.1 s) of both. Newtons; pokes without ``series`` are skipped.
    """
    rows = []
    for p in pokes:
        if p.series is None:
            continue
        t_sim, f_sim = simulate_series(mesh, material, p, config)
        t_m, d_m, f_m = p.series
        resid = np.interp(t_m, t_sim, f_sim) - f_m
        holding = d_m >= d_m.max() - 1e-12
        t_hold = t_m[holding] - t_m[holding][0]
        first, last = t_hold <= 0.1, t_hold >= t_hold[-1] - 0.1
        sim_hold = np.interp(t_m[holding], t_sim, f_sim)
        rows.append({'poke': p.poke_id, 'speed_m_s': p.speed,
                     'push_rms_N': float(np.sqrt(np.mean(resid[~holding] ** 2))),
                     'push_mean_N': float(np.mean(resid[~holding])),
                     'hold_rms_N': float(np.sqrt(np.mean(resid[holding] ** 2))),
                     'hold_mean_N': float(np.mean(resid[holding])),
                     'relaxation_measured_N': float(f_m[holding][first].mean()
                                                    - f_m[holding][last].mean()),
                     'relaxation_replica_N': float(sim_hold[first].mean()
                                                   - sim_hold[last].mean())})
    return {'pokes': rows}


def truth_section(data):
    """Return ``(compression, section_xz)`` stored in the data file ``data``, or None.

    Only a single ``.npz`` with ``section_xz`` (``make_ball_plate.py``) holds one.
    """
    path = Path(str(data))
    if path.suffix != '.npz' or not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        if 'section_xz' not in z:
            return None
        return float(z['section_depth']), np.asarray(z['section_xz'], float)


def camera_views_file(data) -> Optional[Path]:
    """Return ``<data stem>_camera.npz`` beside a plate-on-ball data file, or None."""
    path = Path(str(data))
    if path.suffix != '.npz':
        return None
    views = path.with_name(f'{path.stem}_camera.npz')
    return views if views.is_file() else None


def main(argv=None) -> int:
    """Run the evaluation; print and write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('replica', help='replica directory')
    ap.add_argument('--h-fine', type=float, default=0.0075, help='refined mesh, m (0: skip)')
    ap.add_argument('--clouds', default=None, help='glob of push files with camera clouds')
    ap.add_argument('--camera', default=None, help='camera views of the loaded ball '
                    '(make_ball_camera.py; default: <data>_camera.npz beside the data)')
    ap.add_argument('--map', action='store_true', help='residual map of the held-out pokes '
                    '(DIR/residual_map.png and residual_map in the JSON)')
    ap.add_argument('--map-pokes', type=int, default=0, help='map this many pokes not used '
                    'in training (the held-out ones first; default: the held-out ones)')
    ap.add_argument('--phases', action='store_true',
                    help='force-time residual by phase (push, hold) on held-out series')
    args = ap.parse_args(argv)
    started = time.monotonic()
    root = Path(args.replica)
    desc = read_description(root)
    figures = desc['figures']
    material = Material(**desc['material'])
    config = SceneConfig(**desc['config'])
    h = desc['mesh']['resolution_m']
    mesh = read_vtk(root / 'body.vtk', h)
    data = load_pokes(figures['data'])
    held = subset([p for p in data.pokes if p.poke_id in figures['held_out']], 5)
    result = {'replica': str(root), 'chosen': figures.get('chosen'),
              'material': desc['material'], 'young_Pa': desc['young_Pa'],
              'poisson': desc['poisson'], 'h_m': h,
              'figures': {k: figures[k] for k in ('scaling', 'paper') if k in figures},
              'reproduced': summary(evaluate(mesh, material, held, config))}
    if args.phases:
        result['phases'] = phase_residuals(mesh, material, held, config)
    if args.h_fine:
        coarse, fine = (replica_body(data, size)[0] for size in (h, args.h_fine))
        rows = []
        for p in held:
            row = {'poke': p.poke_id, 'measured_N': float(p.force[-1])}
            for label, m in (('h', coarse), ('h_fine', fine)):
                d, f = simulate_loading(m, material, p, config)
                row[label] = float(force_at(d, f, p.depth[-1:])[0])
            rows.append(row)
        change = [r['h_fine'] / r['h'] - 1 for r in rows]
        result['resolution'] = {'h_m': h, 'h_fine_m': args.h_fine, 'nodes': len(coarse.nodes),
                                'nodes_fine': len(fine.nodes), 'pokes': rows,
                                'median_change_pct': 100 * float(np.median(change))}
    if args.clouds:
        rows = []
        for f in sorted(glob.glob(args.clouds)):
            with np.load(f, allow_pickle=False) as z:
                if Path(f).stem not in figures['held_out']:
                    continue
                start = z['cloud_start']
                cloud = np.asarray(z['cloud'][start[-2]:start[-1]], float)
                depth = float(z['depths'][-1])
                row = contour_error(mesh, material, config, np.asarray(z['xy'], float), depth,
                                    cloud)
            rows.append(dict(row, poke=Path(f).stem, depth_m=depth))
        result['contour'] = {'pokes': rows, 'median_error_pct':
                             float(np.median([r['error_pct'] for r in rows])) if rows else None}
    section = truth_section(figures['data'])
    camera_file = Path(args.camera) if args.camera else camera_views_file(figures['data'])
    map_section = None
    if section is not None:
        outline, centre, actual = ball_section(mesh, material, config, section[0])
        result['section'] = dict(section_error(section[1], outline, centre),
                                 compression_m=actual, compression_truth_m=section[0])
        map_section = {'outline': outline, 'centre': centre, 'truth': section[1],
                       'camera': None}
        if camera_file is not None and camera_file.is_file():
            views = read_camera_views(camera_file)
            result['camera_section'] = dict(
                ball_camera_figures(views, outline, section[1], centre), file=str(camera_file))
            biases = result['camera_section']['rest_corrected']['bias_estimates_m']
            map_section['camera'] = camera_section(np.concatenate(
                [remove_depth_bias(pts, pose, b) for pts, pose, b in
                 zip(views['loaded'], views['pose'], biases)]), (centre[0], 0.0))
    if args.map:
        mapped = held
        if args.map_pokes > len(held):  # more sites: the first pokes outside the training set
            extra = [p for p in data.pokes if p.poke_id not in figures['train']
                     and p.poke_id not in figures['held_out']]
            mapped = held + subset(extra[:args.map_pokes - len(held)], 5)
        rmap = residual_map(mesh, material, config, mapped, map_section)
        rmap['curves']['surface'] = data.surface_points
        result['residual_map_pokes'] = [p.poke_id for p in mapped]
        result['residual_map'] = rmap['numbers']
        plot_residual_map(rmap, root / 'residual_map.png',
                          f'{root.name}: held-out residual of one homogeneous replica '
                          f'(E {desc["young_Pa"] / 1e3:.1f} kPa, nu {desc["poisson"]:.2f})')
        result['residual_map']['png'] = str(root / 'residual_map.png')
    result['seconds'] = time.monotonic() - started
    text = json.dumps(result, indent=1, default=float)
    (root / 'evaluation.json').write_text(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
