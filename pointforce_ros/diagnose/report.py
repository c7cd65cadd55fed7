"""Write a :class:`~pointforce_ros.diagnose.run.DiagnoseReport` as Markdown with PNG plots.

``write_report(report, out_dir)`` creates ``out_dir/report.md`` and, next to it:

* ``residual_before.png`` / ``residual_after.png``: held-out normal-force residual against
  depth, against time in the poke (coloured by phase), and the per-poke RMSE over the surface;
* ``selection.png``: held-out RMSE after each selection round with the sensor-noise level, and
  per-poke RMSE before against after;
* ``worst_poke.png``: the poke with the largest residual before selection, measured and
  predicted force against depth, before and after;
* ``probe_trials.png``: per-trial probe force RMSE before and after (when trials were scored);
* ``effects.json``: the accepted effects as ``ContactModel.effects`` stores them;
* ``summary.json``: the numbers of the report (:func:`summary_dict`): accepted effects with
  uncertainty, held-out sample and model RMSE before and after, probe-trial errors.

Matplotlib runs on the Agg backend (no display needed).
"""

import json
from pathlib import Path

import numpy as np

from pointforce_ros.effects.accepted import effects_to_dict
from pointforce_ros.effects.library import spec

PHASE_COLOURS = {'d<0': '#999999', 'loading': '#1f77b4', 'hold': '#2ca02c',
                 'unloading': '#d62728'}


def _phases(resid, speed_per_sample):
    slow = np.abs(resid['v']) < 0.1 * speed_per_sample
    return np.where(resid['d'] < 0, 'd<0',
                    np.where(slow, 'hold', np.where(resid['v'] > 0, 'loading', 'unloading')))


def _residual_figure(plt, report, resid, title, path):
    phase = _phases(resid, _poke_speed(report, resid)[resid['poke']])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for name, colour in PHASE_COLOURS.items():
        sel = phase == name
        axes[0].plot(resid['d'][sel] * 1e3, resid['normal'][sel], '.', ms=2, color=colour,
                     label=name)
        axes[1].plot(resid['t'][sel], resid['normal'][sel], '.', ms=2, color=colour)
    axes[0].set_xlabel('displacement d (mm)')
    axes[0].set_ylabel('normal force residual (N)')
    axes[0].legend(markerscale=5, fontsize=8)
    axes[1].set_xlabel('time in poke (s)')
    axes[1].set_ylabel('normal force residual (N)')
    lengths = np.bincount(resid['poke'], minlength=len(report.ids))
    rms = np.sqrt(np.bincount(resid['poke'], weights=resid['norm'] ** 2,
                              minlength=len(report.ids)) / np.maximum(lengths, 1))
    sc = axes[2].scatter(report.points[:, 0] * 1e3, report.points[:, 1] * 1e3, c=rms, s=60,
                         cmap='viridis')
    fig.colorbar(sc, ax=axes[2], label='per-poke RMSE (N)')
    axes[2].set_xlabel('x (mm)')
    axes[2].set_ylabel('y (mm)')
    axes[2].set_aspect('equal', adjustable='datalim')
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _poke_speed(report, resid):
    """Per-poke loading speed estimated from the residual table (m/s)."""
    out = np.zeros(len(report.ids))
    for k in range(len(report.ids)):
        v = resid['v'][resid['poke'] == k]
        out[k] = np.median(v[v > 0.2 * v.max()]) if len(v) and v.max() > 0 else 1e-3
    return out


def _selection_figure(plt, report, path):
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    labels = ['base'] + [f'+ {r.chosen}' for r in report.rounds if r.chosen]
    values = [r.rmse for r in report.rounds]
    axes[0].bar(range(len(values)), values, color='#1f77b4')
    axes[0].axhline(report.noise_rms, color='k', ls='--', label='sensor noise')
    axes[0].set_xticks(range(len(values)), labels[:len(values)], rotation=20)
    axes[0].set_ylabel('held-out RMSE (N)')
    axes[0].legend()
    axes[1].loglog(report.poke_rmse_before, report.poke_rmse_after, 'o')
    lo = float(min(report.poke_rmse_before.min(), report.poke_rmse_after.min()))
    hi = float(max(report.poke_rmse_before.max(), report.poke_rmse_after.max()))
    axes[1].plot([lo, hi], [lo, hi], 'k:', label='no change')
    axes[1].set_xlabel('per-poke held-out RMSE before (N)')
    axes[1].set_ylabel('after (N)')
    axes[1].legend()
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _worst_figure(plt, report, path):
    k = int(np.argmax(report.poke_rmse_before))
    before, after = report.residual_before, report.residual_after
    sel = before['poke'] == k
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    ax.plot(before['d'][sel] * 1e3, before['measured'][sel], '.', ms=3, color='k',
            label='measured')
    ax.plot(before['d'][sel] * 1e3, before['predicted'][sel], '-', color='#d62728',
            label='base model (held out)')
    ax.plot(after['d'][sel] * 1e3, after['predicted'][sel], '-', color='#2ca02c',
            label='with accepted effects (held out)')
    ax.set_xlabel('displacement d (mm)')
    ax.set_ylabel('normal force (N)')
    ax.set_title(f'{report.ids[k]}: worst poke before selection')
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(value: float) -> str:
    return f'{value:.4g}'


def _markdown(report) -> str:
    s = report.settings
    lines = ['# pointforce diagnose', '',
             f'Data: `{report.source}`: {len(report.ids)} point pokes'
             + (f', {report.probe_trials} probe trial(s) present'
                + ('' if report.probe is not None else ' but not scored (see the notes)')
                if report.probe_trials else '')
             + '.', '',
             '## Method', '',
             'Base model: per poke `F = c_i (max(d, 0) / 3 mm)^p`, contact onset tied to the '
             'observed surface (`d = 0`), `c_i` the per-poke force vector at 3 mm (local '
             'stiffness and contact direction, solved on each poke, held-out ones included), '
             '`p` and every effect parameter global and fitted on training pokes only. '
             f'Pokes are split by poke into {s["folds"]} seeded groups (seed {s["seed"]}); '
             'each is held out once. A candidate effect is accepted when, on the held-out '
             f'pokes, a one-sided paired Wilcoxon signed-rank test on per-poke MSE gives '
             f'p < {s["alpha"]}, the {_rule_on(s)} drops by at least '
             f'{s["min_improvement"]:.0%}, the sample RMSE by at least '
             f'{s["resolution"]:.1%} of the median peak force, and '
             f'the penalised score `n ln(MSE) + k ln(n)` (n pokes, k parameters, MSE of the '
             f'{_rule_on(s)}) drops; '
             'greedy forward selection with a backward check. The accepted set must then '
             f'remove at least {s.get("explain", 0.5):.0%} of the systematic held-out model '
             'RMSE (sensor noise removed), or it is named as not accepted and the residual '
             'reported as unexplained; a candidate whose fit fails numerically makes the '
             'verdict inconclusive between it and its rivals. Parameter uncertainty: '
             f'bootstrap over pokes ({s["bootstrap"]} resamples).', '',
             '## Result', '']
    if report.accepted:
        lines.append('Accepted effects (fitted on all pokes):')
        lines.append('')
        lines.append('| effect | parameter | value | std | 95 % interval | unit |')
        lines.append('| --- | --- | --- | --- | --- | --- |')
        for a in report.accepted:
            units = {p.name: p.unit for p in spec(a.name).params}
            for k, v in a.params.items():
                interval = (f'{_fmt(a.low[k])} .. {_fmt(a.high[k])}' if k in a.low else
                            'fixed' if k not in units else '-')
                lines.append(f'| {a.name} ({a.title}) | {k} | {_fmt(v)} | '
                             f'{_fmt(a.std[k]) if k in a.std else "-"} | {interval} | '
                             f'{units.get(k, "")} |')
    else:
        lines.append('No effect was accepted.')
    for name, why in report.not_accepted.items():
        lines += ['', f'**Not accepted: {name}**: {why}.']
    if report.inconclusive:
        lines += ['', f'**Inconclusive** between {", ".join(report.inconclusive)}: '
                  f'{report.inconclusive_reason}.']
    for name, why in report.not_applicable.items():
        lines += ['', f'Does not apply to these data: {name}: {why}.']
    if report.onset is not None:
        lines += ['', f'Camera bias: {report.onset.describe()}.']
        caution = report.offset_disagreement()
        if caution:
            lines += ['', f'**{caution[0].upper() + caution[1:]}.**']
    lines += ['', f'Contact-law exponent p = {report.exponent:.3f}.', '',
              '| held-out force error | before | after |', '| --- | --- | --- |',
              f'| RMSE, point pokes, per sample (N) | {_fmt(report.rmse_before)} | '
              f'{_fmt(report.rmse_after)} |',
              f'| model RMSE, point pokes (N): residual averaged over '
              f'{_fmt(s.get("model_block", 0.25))} s blocks of one phase '
              f'({report.model_coverage:.0%} of the samples) | '
              f'{_fmt(report.model_rmse_before)} | {_fmt(report.model_rmse_after)} |',
              f'| systematic part (noise {_fmt(report.noise_rms)} N removed) | '
              f'{_fmt(report.systematic_before)} | {_fmt(report.systematic_after)} |',
              f'| median per-poke RMSE (N) | {_fmt(float(np.median(report.poke_rmse_before)))}'
              f' | {_fmt(float(np.median(report.poke_rmse_after)))} |',
              ] + _probe_rows(report) + [
              '', 'The sample RMSE includes the F/T white noise, which no model can predict; '
              'the model RMSE averages it out and keeps every structural error slower than a '
              'block. Whether an effect halves the error is judged on the model RMSE: after / '
              f'before = {report.model_rmse_after / max(report.model_rmse_before, 1e-300):.2f} '
              f'({"halved" if report.halved else "not halved"}).', '']
    if report.unexplained:
        lines += ['## Unexplained residual', '',
                  f'The systematic residual after selection ({_fmt(report.systematic_after)} N) '
                  f'exceeds the tolerance ({_fmt(report.tolerance)} N) and no library effect '
                  'explains it. Its structure (share of the normal-residual variance):', '']
    else:
        lines += ['## Residual structure after selection', '',
                  f'Systematic residual {_fmt(report.systematic_after)} N is within the '
                  f'tolerance {_fmt(report.tolerance)} N.', '']
    for f in report.structure_after[:5]:
        lines.append(f'- {f.detail}')
        if f.factor in ('depth', 'phase', 'time_in_poke', 'poke_order') and f.groups:
            lines.append('  ' + '; '.join(f'{g[0]}: mean {_fmt(g[1])} N, rms {_fmt(g[2])} N'
                                          for g in f.groups))
    lines += _probe_section(report)
    lines += ['', '![residual before](residual_before.png)', '',
              '![residual after](residual_after.png)', '', '![selection](selection.png)', '',
              '![worst poke](worst_poke.png)', '', '## Selection rounds', '']
    for k, rnd in enumerate(report.rounds):
        current = ', '.join(rnd.current) or 'base model'
        lines += [f'Round {k + 1}: from {current} (held-out RMSE {_fmt(rnd.rmse)} N); '
                  + (f'accepted **{rnd.chosen}**' if rnd.chosen else 'nothing accepted')
                  + (f'; dropped {", ".join(rnd.removed)}' if rnd.removed else '') + '.', '',
                  '| candidate | k | RMSE (N) | improvement | Wilcoxon p | delta score | '
                  'pokes better | significant |',
                  '| --- | --- | --- | --- | --- | --- | --- | --- |']
        for c in rnd.candidates:
            verdict = 'yes' if c.significant else (f'no: {c.rejected}' if c.rejected else 'no')
            lines.append(f'| {c.name} | {c.n_params} | {_fmt(c.rmse)} | {c.improvement:.1%} | '
                         f'{c.p_value:.2g} | {c.delta_score:.1f} | {c.improved}/'
                         f'{len(report.ids)} | {verdict} |')
        lines.append('')
    if report.not_testable:
        lines += ['## Not testable with these data', '']
        lines += [f'- {name}: {why}' for name, why in report.not_testable.items()]
        lines.append('')
    if report.notes:
        lines += ['## Notes', ''] + [f'- {n}' for n in report.notes] + ['']
    return '\n'.join(lines)


def _rule_on(settings) -> str:
    return 'model RMSE' if settings.get('improvement_on', 'model') == 'model' else 'sample RMSE'


SCHEMA = 'pointforce.diagnose.summary/1'
"""Version of the JSON summary's schema (``summary.json``, ``pointforce diagnose --json``)."""


def summary_dict(report) -> dict:
    """Return the report's numbers as a JSON-ready mapping (``summary.json``).

    Stable keys (schema :data:`SCHEMA`): ``accepted`` (list of ``{name, params, std, low,
    high}``: fitted values in SI with bootstrap standard deviation and 95 % range),
    ``rmse`` (held-out ``sample_before/after``, ``model_before/after``, N), ``unexplained``
    (bool) with ``unexplained_structure`` (the strongest structures seen), ``not_accepted``
    (``{candidate: reason}``: the nearest candidate, or a set that explains too little),
    ``inconclusive`` (effect names whose competition could not be decided, numerical
    failure) with ``inconclusive_reason``, ``not_applicable`` (``{effect: reason}``),
    ``explained`` (share of the systematic model RMSE the accepted set removes, or None).
    Non-finite numbers are ``null``.
    """
    def num(x):
        x = float(x)
        return x if np.isfinite(x) else None

    out = {
        'schema': SCHEMA,
        'source': report.source, 'pokes': len(report.ids), 'settings': dict(report.settings),
        'accepted': [{'name': a.name, 'params': {k: num(v) for k, v in a.params.items()},
                      'std': {k: num(v) for k, v in a.std.items()},
                      'low': {k: num(v) for k, v in a.low.items()},
                      'high': {k: num(v) for k, v in a.high.items()}} for a in report.accepted],
        'rmse': {'sample_before': num(report.rmse_before),
                 'sample_after': num(report.rmse_after),
                 'model_before': num(report.model_rmse_before),
                 'model_after': num(report.model_rmse_after),
                 'model_coverage': num(report.model_coverage),
                 'noise': num(report.noise_rms),
                 'systematic_before': num(report.systematic_before),
                 'systematic_after': num(report.systematic_after)},
        'halved': report.halved, 'halving_judged_on': 'model RMSE',
        'unexplained': bool(report.unexplained),
        'unexplained_structure': [{'factor': f.factor, 'explained': num(f.explained),
                                   'detail': f.detail}
                                  for f in report.structure_after[:3]]
        if report.unexplained else [],
        'not_accepted': dict(report.not_accepted),
        'inconclusive': list(report.inconclusive),
        'inconclusive_reason': str(report.inconclusive_reason),
        'not_applicable': dict(report.not_applicable),
        'explained': num(report.explained),
        'exponent': num(report.exponent),
        'notes': list(report.notes),
    }
    probe = report.probe
    if probe is not None:
        out['probe_trials'] = {
            'trials': len(probe.kinds), 'effects': sorted(probe.effects),
            'force_before': num(probe.force_rmse_before),
            'force_after': num(probe.force_rmse_after),
            'torque_before': num(probe.torque_rmse_before),
            'torque_after': num(probe.torque_rmse_after)}
    return out


def _probe_rows(report) -> list:
    probe = report.probe
    if probe is None:
        return ['| RMSE, probe trials (N) | not scored | not scored |']
    return [f'| RMSE, probe trials: force (N) | {_fmt(probe.force_rmse_before)} | '
            f'{_fmt(probe.force_rmse_after)} |',
            f'| RMSE, probe trials: torque (N m) | {_fmt(probe.torque_rmse_before)} | '
            f'{_fmt(probe.torque_rmse_after)} |']


def _probe_section(report) -> list:
    probe = report.probe
    if probe is None:
        return []
    label = ', '.join(probe.effects) or 'no effect'
    lines = ['## Probe trials', '',
             f'{len(probe.kinds)} trial(s) with ground truth, answered by the contact service '
             f'from the point model (ours) learned on all point pokes, before (no effect) and '
             f'after ({label}); shape constant c = {_fmt(probe.shape_constant * 1e3)} mm. '
             'A series compliance is added back only on trials measured through the arm '
             '(generated trials are the clean response of the object); a viscoelastic effect '
             'answers the instantaneous force.', '',
             '| trial | probe | steps | force RMSE before (N) | after (N) | torque RMSE '
             'before (N m) | after (N m) |', '| --- | --- | --- | --- | --- | --- | --- |']
    for k, kind in enumerate(probe.kinds):
        lines.append(f'| {k} | {kind} | {probe.steps[k]} | {_fmt(probe.force_before[k])} | '
                     f'{_fmt(probe.force_after[k])} | {_fmt(probe.torque_before[k])} | '
                     f'{_fmt(probe.torque_after[k])} |')
    if probe.compliance is not None:
        lines += ['', f'Series compliance: {probe.compliance.describe()}. On point pokes alone '
                  'a stiff arm only reparametrises each curve (`d_meas = d + C f`, the poke\'s '
                  'own force); a wide probe bends it by the total force of all its contacts.']
    if probe.coupling is not None:
        c = probe.coupling
        lines += ['', f'Spatial coupling beyond the shape function: {c.describe()}.']
        if c.accepted:
            lines += ['', f'It is written to `effects.json` as `spatial_coupling.shape_constant'
                      f' = {c.fitted:.4g}` m: a learner that reads the file must learn with '
                      'this shape constant (the shape constant is a model parameter, not a '
                      'correction of the pokes).']
    lines += ['', '![probe trials](probe_trials.png)', '']
    return lines


def _probe_figure(plt, report, path):
    probe = report.probe
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(probe.kinds))
    ax.bar(x - 0.2, probe.force_before, 0.4, label='before', color='#d62728')
    ax.bar(x + 0.2, probe.force_after, 0.4, label='after', color='#1f77b4')
    ax.set_xticks(x, [f'{k}: {kind}' for k, kind in enumerate(probe.kinds)], rotation=30)
    ax.set_ylabel('force RMSE per trial (N)')
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_report(report, out_dir) -> Path:
    """Write ``report.md``, the PNG plots, ``effects.json`` and ``summary.json``; return the .md.

    Raises:
        OSError: ``out_dir`` cannot be created or written.

    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _residual_figure(plt, report, report.residual_before,
                     f'Held-out residual, base model (RMSE {report.rmse_before:.3g} N)',
                     out / 'residual_before.png')
    _residual_figure(plt, report, report.residual_after,
                     'Held-out residual with ' + (', '.join(report.accepted_names) or
                                                  'no effect')
                     + f' (RMSE {report.rmse_after:.3g} N)', out / 'residual_after.png')
    _selection_figure(plt, report, out / 'selection.png')
    _worst_figure(plt, report, out / 'worst_poke.png')
    if report.probe is not None:
        _probe_figure(plt, report, out / 'probe_trials.png')
    (out / 'effects.json').write_text(json.dumps(effects_to_dict(report), indent=2))
    (out / 'summary.json').write_text(json.dumps(summary_dict(report), indent=2))
    path = out / 'report.md'
    path.write_text(_markdown(report))
    return path
