#!/usr/bin/env python3
"""Does a poked point's offset from the cloud's local surface predict its onset? (a study)

Session 43. Each figure fixture's 30 pokes are at points of the scanned cloud. If a point sat
off the surface through the camera's per-point noise, its contact onset would move with that
offset, and a smoothed surface would predict it. Per object: each poke's power-law onset
``d0`` (:meth:`~pointforce_ros.response.ours.ContactGpModel.fit_curve`) and its point's
height above a plane (``deg 1``) or a quadric (``deg 2``) fitted, in the poke's normal frame,
to the cloud within ``r`` of it; printed: the offset's spread, its correlation with ``d0`` and
the spread of ``d0`` less and plus the offset.

Session 43 (record ``onset_offset.log``): the correlations lie between -0.41 and +0.60; only
the dome with a plane over 12 mm takes a fifth off the onset's spread (0.52 -> 0.42 mm): the
dome's curvature under the plane, which session 42 found the onset to follow; elsewhere at
most 7 % (plush, a quadric over 12 mm, 0.147 -> 0.137 mm). The cloud is
smooth; the onset's spread is a bias field between pokes, not the points' own noise.

Usage: python data/figures/onset_offset.py [--objects dome plush thin_layer] (seconds).
"""

import argparse

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.lab.figures import load_poke_fixture
from pointforce_ros.response.ours import ContactGpModel

RADII = (0.003, 0.005, 0.008, 0.012)


def offset(tree, points, p, n, radius, degree):
    """Height (m) of the fitted local surface above ``p`` along ``n``, minus ``p``'s (0)."""
    u = np.cross(n, [1.0, 0.0, 0.0])
    if np.linalg.norm(u) < 0.1:
        u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    rel = points[tree.query_ball_point(p, radius)] - p
    a, b = rel @ u, rel @ v
    cols = [np.ones_like(a), a, b] + ([a * a, a * b, b * b] if degree == 2 else [])
    return float(np.linalg.lstsq(np.stack(cols, axis=1), rel @ n, rcond=None)[0][0])


def main(argv=None):
    """Print one line per object, degree and radius."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=['dome', 'plush', 'thin_layer'])
    args = parser.parse_args(argv)
    model = ContactGpModel(law='power')
    for name in args.objects:
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        tree = cKDTree(surface.points)
        d0 = np.array([model.fit_curve(c, 'power')[0][0] for c in curves])
        print(f'{name}: onset d0 spread {d0.std() * 1e3:.3f} mm over {len(curves)} pokes')
        for degree in (1, 2):
            for radius in RADII:
                off = np.array([offset(tree, surface.points, c.point, c.normal, radius, degree)
                                for c in curves])
                print(f'  deg {degree} r {radius * 1e3:2.0f} mm: offset spread '
                      f'{off.std() * 1e3:.3f} mm, correlation with d0 '
                      f'{np.corrcoef(off, d0)[0, 1]:+.2f}; spread of d0 - offset '
                      f'{(d0 - off).std() * 1e3:.3f} mm, d0 + offset {(d0 + off).std() * 1e3:.3f}'
                      ' mm', flush=True)


if __name__ == '__main__':
    main()
