"""Cost of :func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty` per single query.

On the newest model a ``pointforce demo`` run saved and the demo's nine planner queries (warm:
the perturbed simulators and projections built once), against one plain contact solve.
Usage: ``python -m pointforce_ros.bringup.bench_uncertainty out/demo``
"""

import glob
import sys
import time

import numpy as np

from pointforce_ros.bringup.demo import demo_query_set
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.contact.uncertainty import wrench_uncertainty
from pointforce_ros.model.files import load_model
from pointforce_ros.sim.objects import load_object


def main(out: str) -> None:
    """Time the nine queries five times each and print the medians."""
    model = load_model(sorted(glob.glob(out + '/cell/models/model-v*.npz'))[-1])
    queries = demo_query_set(load_object('lamb'))
    cov = np.array([[0.48 ** 2, 0.0], [0.0, 39.0 ** 2]])
    for name, mesh, pose, a, tc in queries:      # warm: perturbed simulators, projections
        wrench_uncertainty(model, mesh, [pose], a, tc, shape_cov=cov, relative_std=0.03)
    wall, cpu = [], []
    for _ in range(5):
        for name, mesh, pose, a, tc in queries:
            t, c = time.perf_counter(), time.process_time()
            wrench_uncertainty(model, mesh, [pose], a, tc, shape_cov=cov, relative_std=0.03)
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
    sim = ContactSimulator(model.surface, model.response, model.shape_constant,
                           decay=model.shape_decay, decay_law=model.shape_decay_law,
                           near=model.shape_near)
    plain = []
    for _ in range(5):
        for name, mesh, pose, a, tc in queries:
            t = time.perf_counter()
            sim.query_batch(mesh, [pose], a, tc)
            plain.append(time.perf_counter() - t)
    print(f'wrench_uncertainty per query: median {1e3 * np.median(wall):.1f} ms wall, '
          f'{1e3 * np.median(cpu):.1f} ms CPU (p90 {1e3 * np.percentile(wall, 90):.1f} ms); '
          f'one plain solve {1e3 * np.median(plain):.1f} ms; {len(model.surface)} surface points')


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'out/demo')
