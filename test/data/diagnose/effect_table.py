"""The closing-note table: every library effect at the cell's scenario size, two objects.

For each effect, the cell pokes an object with the effect of ``config/scenarios/<name>.yaml``
(its parameters as the cell's scenarios use them) plus the F/T noise of
``config/scenarios/ft_noise.yaml`` (0.03 N per sample, a UR e-Series tool sensor), and
``pointforce diagnose`` is run on the pokes without being told the effect. The table says
whether diagnose named it, the fitted against the true parameter, and the held-out RMSE before
and after, per sample and as the model RMSE (white noise averaged out; the halving criterion
uses the model RMSE, see ``DiagnoseReport``). Objects:

* ``analytic``: the heterogeneous half-space of ``datasets.py`` (stiffness ripple 30 %);
* ``lamb`` (or any FEM object with a live cache): ``fem_cell_object(spec, LiveContact)``, the
  FEM live contact path the demo uses. Pokes stop at ``depth_limit`` (7 mm by default) so
  that even with the 2 mm camera bias the true depth stays inside the live cache's range
  (beyond it the live path extrapolates linearly, which the curves would show as softening).

With ``series_compliance`` on ``analytic`` a second row, ``series_compliance+probes``, adds
12 probe trials measured through the same arm (a point poke cannot name a 20 N/mm arm).

Usage (2-3 minutes on a loaded 2-core machine; prints a progress line per set)::

    nice -n 10 python test/data/diagnose/effect_table.py [--objects analytic,lamb]
        [--sets clean,camera_bias,...] [--pokes 16] [--seed 1]
"""

import argparse
import importlib.util
import sys
import time
from pathlib import Path

from pointforce_ros.sim import disturbances as ce
from pointforce_ros.sim.scenario import load_scenario, Scenario
from pointforce_ros.sim.session import simulate_campaign
from pointforce_ros.diagnose import diagnose

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location('diagnose_datasets_table', HERE / 'datasets.py')
datasets = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(datasets)
_spec = importlib.util.spec_from_file_location('diagnose_probe_trials_table',
                                               HERE / 'probe_trials.py')
probe_trials = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(probe_trials)

PROBE_SET = 'series_compliance+probes'
"""Extra row (analytic object only): the ``series_compliance`` pokes plus 12 probe trials
measured through the same arm (``probe_trials.make_trials(..., compliance=...)``); the pokes
alone cannot name a 20 N/mm arm, the trials can."""

# scenario file -> (library effect, true parameters in library units, campaign extras)
SETS = {
    'clean': (None, {}, {}),
    'camera_bias': ('surface_offset', {'offset': 0.002}, {}),
    'ft_bias': ('ft_bias', {'fx': 0.8, 'fy': -0.5, 'fz': 1.2}, {'tare': False}),
    'ft_drift': ('ft_drift', {'rx': 0.01, 'ry': -0.008, 'rz': 0.02}, {}),
    'time_offset': ('time_offset', {'offset': 0.008}, {}),
    'viscoelastic': ('viscoelastic', {'g': 0.25}, {}),
    'hysteresis': ('hysteresis', {'eta': 0.15, 'transition': 0.0005}, {}),
    'series_compliance': ('series_compliance', {'compliance': 1.0 / 20000.0}, {}),
    'plastic_set': ('plastic_set', {'max_set': 0.0008, 'n0': 3.0}, {'repeats': 4}),
    'friction': ('friction', {'mu': 0.4}, {'normal_tilt_deg': (8.0, 20.0)}),
}
"""The viscoelastic scenario is a two-term Prony series (g 0.15 + 0.10, tau 0.5 s and 5 s);
the library's term is a Prony series on fixed relaxation times: its total relaxing fraction
``g`` is compared with the total 0.25."""


def cell_object(name: str):
    """Return ``(cell object, campaign settings)`` of ``analytic`` or a FEM object."""
    common = dict(datasets.COMMON)
    if name == 'analytic':
        return datasets.OBJECT, common
    from pointforce_ros.sim.fem.live import LiveContact
    from pointforce_ros.sim.generate import fem_cell_object
    from pointforce_ros.sim.objects import load_object
    spec = load_object(name)
    live = LiveContact.load(spec.name, build=False)
    common.update(force_limit=min(spec.force_cap, 6.0), depth_limit=0.007, standoff=0.004)
    return fem_cell_object(spec, live), common


def records_for(obj, common: dict, set_name: str, pokes: int, seed: int):
    """Poke ``obj`` under the scenario ``set_name`` plus the cell's F/T noise."""
    _, _, extra = SETS[set_name]
    scenario = load_scenario(set_name)
    noise = load_scenario('ft_noise').effects
    effects = tuple(e for e in scenario.effects if not isinstance(e, ce.FtNoise)) + noise
    campaign = {**common, **extra}
    if 'repeats' in campaign:
        campaign['count'] = max(pokes // campaign['repeats'], 4)
    else:
        campaign['count'] = pokes
    return simulate_campaign(obj, Scenario(set_name, seed=scenario.seed, effects=effects),
                             seed=seed, **campaign)


def row(object_name: str, set_name: str, report, seconds: float) -> str:
    """One Markdown table row."""
    effect, truth, _ = SETS[set_name.split('+')[0]]
    accepted = report.accepted_names
    if effect is None:
        verdict = 'ok' if not accepted else 'FALSE POSITIVE'
    else:
        verdict = 'detected' if effect in accepted else 'missed'
        if accepted and set(accepted) - {effect}:
            verdict += ' + wrong ' + ','.join(sorted(set(accepted) - {effect}))
    fitted = report.effects().get(effect, {}) if effect else {}
    stds = {a.name: a.std for a in report.accepted}.get(effect, {})
    params = []
    for key, true in truth.items():
        got = fitted.get(key)
        text = f'{key} {_num(got)}' + (f' +- {_num(stds[key])}' if key in stds else '')
        text += f' (true {_num(true) if true is not None else "2-term"})'
        if got is not None and true:
            text += f' {100 * (got / true - 1):+.0f} %'
        params.append(text)
    notes = []
    if effect and effect not in accepted and report.rounds:
        tried = {c.name: c for c in report.rounds[0].candidates}.get(effect)
        if tried is not None:
            notes.append(f'first round: {effect} p={tried.p_value:.2g}, RMSE '
                         f'{-100 * tried.improvement:+.1f} % (model '
                         f'{-100 * tried.model_improvement:+.1f} %), penalised score '
                         f'{tried.delta_score:+.1f}, {tried.improved}/'
                         f'{len(report.ids)} pokes better'
                         + (f', refused: {tried.rejected}' if tried.rejected else ''))
    if report.unexplained:
        notes.append('unexplained residual')
    if report.probe is not None:
        notes.append(f'probe trials: force RMSE {report.probe.force_rmse_before:.3f} -> '
                     f'{report.probe.force_rmse_after:.3f} N'
                     + (f', stiffness {1e-3 / report.probe.compliance.fitted:.3g} N/mm, '
                        f'p = {report.probe.compliance.p_value:.2g}'
                        if report.probe.compliance is not None else ''))
    if report.onset is not None and set_name in ('clean', 'camera_bias'):
        notes.append(f'onset offset {report.onset.offset * 1e3:.2f} mm')
    return (f'| {object_name} | {set_name} | {verdict} | {", ".join(accepted) or "-"} | '
            f'{"; ".join(params) or "-"} | {report.rmse_before:.4f} -> {report.rmse_after:.4f} | '
            f'{report.model_rmse_before:.4f} -> {report.model_rmse_after:.4f} | '
            f'{report.model_rmse_after / report.model_rmse_before:.2f} | '
            f'{"; ".join(notes) or "-"} | {seconds:.0f} |')


def _num(x) -> str:
    return '-' if x is None else f'{x:.3g}'


def main(argv=None) -> int:
    """Print the table (progress lines go to stderr)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', default='analytic,lamb')
    parser.add_argument('--sets', default=','.join(SETS))
    parser.add_argument('--pokes', type=int, default=16)
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--bootstrap', type=int, default=5)
    parser.add_argument('--no-probes', dest='probes', action='store_false',
                        help=f'leave out the {PROBE_SET} row')
    parser.add_argument('--improvement-on', default='model', choices=('sample', 'model'),
                        help="diagnose's improvement_on (the relative-improvement rule)")
    args = parser.parse_args(argv)
    sets = [s for s in args.sets.split(',') if s]
    unknown = [s for s in sets if s not in SETS]
    if unknown:
        parser.error(f'unknown set(s) {unknown}; known: {list(SETS)}')
    rows = []
    started = time.monotonic()
    for object_name in [o for o in args.objects.split(',') if o]:
        obj, common = cell_object(object_name)
        for k, set_name in enumerate(sets):
            t0 = time.monotonic()
            records = records_for(obj, common, set_name, args.pokes, args.seed)
            report = diagnose(records, seed=0, bootstrap=args.bootstrap,
                              improvement_on=args.improvement_on)
            seconds = time.monotonic() - t0
            rows.append(row(object_name, set_name, report, seconds))
            if object_name == 'analytic' and set_name == 'series_compliance' and args.probes:
                t0 = time.monotonic()
                trials = probe_trials.make_trials(
                    0.004, count=6, compliance=SETS['series_compliance'][1]['compliance'])
                report = diagnose(records, seed=0, bootstrap=args.bootstrap,
                                  improvement_on=args.improvement_on, probes=trials,
                                  surface=probe_trials.top_surface(), shape_constant=0.004)
                rows.append(row(object_name, PROBE_SET, report, time.monotonic() - t0))
            print(f'[effect_table] {object_name} {k + 1}/{len(sets)} {set_name}: '
                  f'{report.accepted_names or "nothing"} accepted, {seconds:.0f} s '
                  f'(total {time.monotonic() - started:.0f} s)', file=sys.stderr, flush=True)
    print('| object | scenario | verdict | accepted | fitted (true) | sample RMSE before -> '
          'after (N) | model RMSE before -> after (N) | model after/before | notes | s |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    print('\n'.join(rows))
    return 0


if __name__ == '__main__':
    sys.exit(main())
