#!/usr/bin/env python3
"""Figure 2 (line and cylinder probe trials) under each decay law of the simulator (a study).

Session 30 built the ``'layer'`` decay law (each query's tail length times the layer proxy read
off the point response, :func:`~pointforce_ros.contact.simulator.layer_proxy`) for the demo's
low answers over the lamb's bone. Before it can be the default it must not cost figure 2:
this runs :func:`~pointforce_ros.lab.figures.figure_probes` on every object with fixtures,
once per law (``(c, L)`` identified from the other trials under that law, as the figure does),
and prints ours' force RMSE (all, line, cylinder) and its share of the peak force. The paper
simulator's baseline does not depend on the law and is not re-run (``paper_draws = 0``);
figure 2's ratio goal is read against the baseline of ``pointforce figures``.

Result (session 30, 3 training draws per object, record ``probe_layer_law.log``): the law costs
figure 2 on every object measured: lamb 0.913 -> 1.062 N (8.1 -> 9.4 % of the peak), dome 0.311
-> 0.756 N (3.3 -> 8.0 %; the paper's simulator scores 0.742 N, so the ratio goal would fail),
thin layer 1.428 -> 2.356 N (6.9 -> 11.4 %, past the 10 % goal). On the dome the cause is the
proxy's dependence on the point model: ``(c, L)`` are identified with the model of every poke,
the trials answered by 10-poke models, whose proxy at the trial sites is 0.6-1.0 against the
full model's 0.4-0.67 (the thin rim unresolved). With every simulator given the full model's
proxy (``--proxy frozen``) the dome scores 0.333 N (penetration law 0.311); with each model's
own proxy against the full model's median stiffening (``--proxy absolute``) 0.454 N. But the
frozen proxy does not rescue the others: lamb 1.216 N, thin layer 2.564 N (12.4 %): there the
law itself misfits the trials (their leave-one-out ``(c, L)`` scatter, c 1.5-17 mm, L 8-32 mm).
It stays a choice (``shape_decay_law``), not the default.

Usage: python data/figures/probe_layer_law.py [--objects plush,lamb] [--laws penetration,layer]
       [--repeats 10]
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pointforce_ros.contact import simulator
from pointforce_ros.lab.figures import (bake_depths, figure_probes, load_poke_fixture,
                                        load_probe_fixture)
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.sim.objects import list_objects

HERE = Path(__file__).resolve().parent
OWN_PROXY = simulator.layer_proxy
OWN_THICKNESS = simulator.ContactSimulator.layer_thickness


def freeze(how, curves, surface):
    """Patch the simulator's proxy to the all-poke model's (``frozen``) or its median."""
    full = ContactGpModel().fit(list(curves), surface).bake(surface, bake_depths(curves))
    onsets = np.asarray(full.onsets(), dtype=float)
    onsets = np.where(np.isfinite(onsets), onsets, 0.0)
    ratio, ok = simulator.layer_stiffening(full, onsets)
    reference = float(np.median(ratio[ok]))
    fixed = simulator.layer_proxy(full, onsets)
    simulator.layer_proxy = OWN_PROXY
    simulator.ContactSimulator.layer_thickness = OWN_THICKNESS
    if how == 'frozen':
        simulator.ContactSimulator.layer_thickness = lambda self: fixed
    else:
        simulator.layer_proxy = lambda response, onsets: OWN_PROXY(response, onsets, reference)


def main():
    """Print one line per object and law; write ``probe_layer_law.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', default=None)
    parser.add_argument('--laws', default='penetration,layer')
    parser.add_argument('--repeats', type=int, default=10)
    parser.add_argument('--proxy', default='own', choices=('own', 'frozen', 'absolute'),
                        help="the 'layer' law's proxy: each model's own (the product's), the "
                        "all-poke model's for every simulator, or each model's against the "
                        "all-poke model's median stiffening")
    args = parser.parse_args()
    objects = args.objects.split(',') if args.objects else list_objects()
    rows = []
    for name in objects:
        try:
            surface, curves, _ = load_poke_fixture(name, say=lambda s: None)
            trials, dent, _ = load_probe_fixture(name, say=lambda s: None)
        except Exception as exc:      # an object without fixtures
            print(f'{name}: skipped ({exc})')
            continue
        if args.proxy != 'own':
            freeze(args.proxy, curves, surface)
        for law in args.laws.split(','):
            simulator.DECAY_LAW = law      # what every simulator of the figure is built with
            t0 = time.monotonic()
            res = figure_probes(curves, surface, trials, dent, repeats=args.repeats,
                                paper_draws=0, say=lambda s: None)
            ours = res['rmse']['ours']
            row = dict(object=name, law=law, proxy=args.proxy, force=ours['force'],
                       line=ours['force_line'], cylinder=ours['force_cylinder'],
                       peak=res['peak_force'], shape=res['c']['with_decay'])
            rows.append(row)
            print(f'{name:10s} {law:11s} ({args.proxy}): ours {ours["force"]:.3f} N (line '
                  f'{ours["force_line"]:.3f}, cylinder {ours["force_cylinder"] or 0:.3f}), '
                  f'{100 * ours["force"] / res["peak_force"]:.1f} % of the peak '
                  f'{res["peak_force"]:.2f} N; (c mm, L mm): '
                  + ', '.join(f'{1e3 * c:.1f}/{1e3 * L:.0f}' for c, L, _ in res['c']['with_decay'])
                  + f' [{time.monotonic() - t0:.0f} s]', flush=True)
    out = HERE / f'probe_layer_law_{"_".join(objects)}_{args.proxy}.json'
    out.write_text(json.dumps({'rows': rows}, indent=1) + '\n')


if __name__ == '__main__':
    main()
