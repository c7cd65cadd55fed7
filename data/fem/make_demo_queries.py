"""Precompute the FEM ground truth of the demo's planner queries (``pointforce demo``).

For each query of :func:`pointforce_ros.bringup.demo.demo_query_set` (sphere, paddle, cylinder at
three poses each) the full nonlinear FEM solve (:func:`pointforce_ros.sim.fem.indentation.
probe_wrench_full`, element size ``mesh_live`` of the object) gives the wrench on the probe at
that pose, reached by pushing along the probe's +z axis. Writes ``demo_queries_<object>.npz``
(names (Q,), force (Q, 3) N, torque (Q, 3) N m about each query's torque centre, base frame).

Usage: python data/fem/make_demo_queries.py [--object lamb]   (minutes per query)
"""

import argparse
import time
from pathlib import Path

import numpy as np

from pointforce_ros.sim.fem.indentation import probe_wrench_full
from pointforce_ros.sim.objects import load_object
from pointforce_ros.bringup.demo import demo_query_set

HERE = Path(__file__).resolve().parent


def main():
    """Compute and write the fixture."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    spec = load_object(args.object)
    queries = demo_query_set(spec)
    names = [q[0] for q in queries]
    # Each finished query is kept and skipped on the next run (an interrupted run resumes).
    partial = HERE / f'demo_queries_{spec.name}.partial.npz'
    done = {}
    if partial.exists():
        with np.load(partial, allow_pickle=False) as z:
            done = {str(n): (f, m) for n, f, m in zip(z['names'], z['force'], z['torque'])}
    start = time.monotonic()
    for k, (name, mesh, pose, approach, centre) in enumerate(queries):
        if name not in done:
            done[name] = probe_wrench_full(spec, mesh, pose, centre, h=spec.mesh_live)
            keys = list(done)
            np.savez(partial, names=np.array(keys), force=np.array([done[n][0] for n in keys]),
                     torque=np.array([done[n][1] for n in keys]))
        print(f'{k + 1}/{len(queries)} {name}: F = {np.round(done[name][0], 3)} N, '
              f'{time.monotonic() - start:.0f} s', flush=True)
    np.savez(HERE / f'demo_queries_{spec.name}.npz', names=np.array(names),
             force=np.array([done[n][0] for n in names]),
             torque=np.array([done[n][1] for n in names]))
    partial.unlink()


if __name__ == '__main__':
    main()
