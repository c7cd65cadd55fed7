"""Confusion matrix of ``pointforce diagnose`` on the independent generator's tables.

Rows: the true effect of a table (:mod:`pointforce_ros.lab.effect_generator`); columns: the
verdict (the accepted effect, ``+``-joined when several, ``nothing``, ``unexplained`` or
``inconclusive``). A *wrong cause* is an accepted effect that is not the true one (on clean
data and on effects outside the library, any accepted effect); those cells are marked ``!``.
Every table goes through the documented CSV import. Usage::

    nice -n 10 python -m pointforce_ros.lab.confusion [--seeds 0,1] [--levels 1,3,10]
        [--pokes 24] [--effects clean,viscoelastic,...] [--json out/confusion.json]
    python -m pointforce_ros.lab.confusion --merge a.json b.json --json all.json

``--merge`` joins the rows of runs made in parallel into one matrix. The committed result,
``test/data/diagnose/confusion.json`` (80 cases, about 40 min on a loaded 2-core machine),
was made by six runs in parallel (``--seeds 0`` and ``--seeds 1``, each with ``--effects``
``clean,camera_bias,ft_bias,ft_drift,time_offset`` / ``viscoelastic,hysteresis`` /
``series_compliance,plastic_set,friction,saturation,crosstalk,periodic``, ``--levels 1,3,10
--pokes 24``) merged with ``--merge``; the one-process equivalent is ``python -m
pointforce_ros.lab.confusion --seeds 0,1 --json test/data/diagnose/confusion.json``.

The goals it checks: no wrong cause anywhere; the right effect named in at least 90 % of the
in-library cases at or above twice the noise floor (``snr >= 2``) with its parameter within
20 % and the held-out model RMSE at most half of before; nothing accepted on clean data.
"""

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List

import numpy as np

from pointforce_ros.diagnose import diagnose
from pointforce_ros.diagnose.report import summary_dict
from pointforce_ros.effects.library import plastic_depth
from pointforce_ros.lab import effect_generator as eg


def verdict(summary: dict) -> str:
    """Return the verdict label of a diagnose summary."""
    names = [a['name'] for a in summary['accepted']]
    if summary['inconclusive']:
        return 'inconclusive'
    if names:
        return '+'.join(sorted(names))
    return 'unexplained' if summary['unexplained'] else 'nothing'


def parameter_error(case: eg.Case, summary: dict) -> float:
    """Largest relative error of the fitted parameters against the truth (nan: not named)."""
    right = eg.library_name(case.effect)
    fitted = {a['name']: a['params'] for a in summary['accepted']}.get(right)
    if fitted is None:
        return float('nan')
    truth = eg.truth(case)
    errors = []
    if 'set3' in truth:
        value = float(plastic_depth(3, fitted['max_set'], fitted['n0']))
        errors.append(abs(value / truth['set3'] - 1.0))
    elif case.effect in ('ft_bias', 'ft_drift'):
        true = np.array(list(truth.values()))
        got = np.array([fitted[k] for k in truth])
        errors.append(float(np.linalg.norm(got - true) / np.linalg.norm(true)))
    else:
        for key, value in truth.items():
            errors.append(abs(fitted[key] / value - 1.0))
    return float(max(errors))


def run_case(case: eg.Case, folder: Path) -> Dict:
    """Generate, import and diagnose one case; return its row."""
    path = eg.write_table(case, folder / (case.label.replace(' ', '_').replace('/', '-')
                                          + '.csv'))
    start = time.time()
    report = diagnose(str(path), seed=0, bootstrap=0)
    summary = summary_dict(report)
    right = eg.library_name(case.effect)
    names = [a['name'] for a in summary['accepted']]
    wrong = [n for n in names if n != right]
    rmse = summary['rmse']
    return {
        'case': case.label, 'effect': case.effect, 'shape': case.shape, 'level': case.level,
        'seed': case.seed, 'restart': case.restart, 'snr': eg.signal_to_noise(case),
        'truth': eg.truth(case), 'verdict': verdict(summary), 'wrong': wrong,
        'right': right is not None and names == [right],
        'param_error': parameter_error(case, summary),
        'model_before': rmse['model_before'], 'model_after': rmse['model_after'],
        'halved': bool(summary['halved']), 'explained': summary['explained'],
        'not_accepted': summary['not_accepted'], 'inconclusive': summary['inconclusive'],
        'warnings': len(report.warnings_seen), 'seconds': round(time.time() - start, 1),
    }


def goals(rows: List[Dict]) -> Dict:
    """Return the goal figures of a sweep."""
    wrong = [r['case'] for r in rows if r['wrong']]
    library = [r for r in rows if eg.library_name(r['effect']) and r['snr'] >= 2.0]
    good = [r for r in library if r['right'] and r['param_error'] <= 0.2 and r['halved']]
    named = [r for r in library if r['right']]
    clean = [r for r in rows if r['effect'] == 'clean']
    return {
        'cases': len(rows), 'wrong_causes': len(wrong), 'wrong_cases': wrong,
        'in_library_at_2x_noise': len(library), 'named': len(named),
        'named_within_20pct_and_halved': len(good),
        'share_named_within_20pct_and_halved': (len(good) / len(library)) if library else None,
        'clean_cases': len(clean),
        'clean_with_nothing_accepted': sum(1 for r in clean if not r['wrong']),
        'warnings': sum(r['warnings'] for r in rows),
    }


def matrix_text(rows: List[Dict]) -> str:
    """Return the confusion matrix as text (wrong-cause cells marked ``!``)."""
    true_keys = []
    for r in rows:
        key = r['effect'] + (f'/{r["shape"]}' if r['shape'] else '')
        if key not in true_keys:
            true_keys.append(key)
    columns = sorted({r['verdict'] for r in rows},
                     key=lambda v: (v in ('nothing', 'unexplained', 'inconclusive'), v))
    counts: Dict = {}
    for r in rows:
        key = r['effect'] + (f'/{r["shape"]}' if r['shape'] else '')
        cell = counts.setdefault((key, r['verdict']), [0, False])
        cell[0] += 1
        cell[1] = cell[1] or bool(r['wrong'])
    width = max(len(k) for k in true_keys) + 2
    cols = [max(len(c), 4) + 2 for c in columns]
    lines = ['true \\ verdict'.ljust(width) + ''.join(c.rjust(w) for c, w in zip(columns, cols))]
    for key in true_keys:
        cells = []
        for c, w in zip(columns, cols):
            n, bad = counts.get((key, c), [0, False])
            cells.append(('' if n == 0 else f'{n}{"!" if bad else ""}').rjust(w))
        lines.append(key.ljust(width) + ''.join(cells))
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Run the sweep, print the matrix and the goals, write the JSON."""
    parser = argparse.ArgumentParser(prog='python -m pointforce_ros.lab.confusion',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', default='0,1')
    parser.add_argument('--levels', default='1,3,10')
    parser.add_argument('--pokes', type=int, default=24)
    parser.add_argument('--effects', default='', help='comma-separated subset (default all)')
    parser.add_argument('--json', default='out/confusion.json', help='where to write rows')
    parser.add_argument('--merge', nargs='+', default=None,
                        help='JSON files of earlier runs to join (no new cases are run)')
    args = parser.parse_args(argv)
    if args.merge:
        runs = [json.loads(Path(p).read_text()) for p in args.merge]
        rows = [row for run in runs for row in run['rows']]
        command = ' && '.join(run['command'] for run in runs)
        return _finish(rows, Path(args.json), command + f' (merged: {len(runs)} runs)')
    cases = eg.sweep(seeds=tuple(int(s) for s in args.seeds.split(',')),
                     levels=tuple(float(v) for v in args.levels.split(',')), pokes=args.pokes)
    if args.effects:
        keep = set(args.effects.split(','))
        cases = [c for c in cases if c.effect in keep]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            row = run_case(case, Path(tmp))
            rows.append(row)
            print(f'{row["case"]:32s} snr {row["snr"]:6.1f} -> {row["verdict"]:24s}'
                  f'{" WRONG" if row["wrong"] else ""} err {row["param_error"]:.2f} '
                  f'model {row["model_before"]:.3g}->{row["model_after"]:.3g} N '
                  f'({row["seconds"]:.0f} s)', flush=True)
    command = 'python -m pointforce_ros.lab.confusion ' + ' '.join(
        sys.argv[1:] if argv is None else argv)
    return _finish(rows, Path(args.json), command.strip())


def _finish(rows: List[Dict], out: Path, command: str) -> int:
    """Print the matrix and the goals; write the JSON."""
    print()
    print(matrix_text(rows))
    figures = goals(rows)
    print()
    print(json.dumps(figures, indent=1))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'command': command, 'goals': figures,
                               'matrix': matrix_text(rows), 'rows': rows}, indent=1,
                              default=float))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
