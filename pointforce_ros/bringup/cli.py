"""The ``pointforce`` command: one entry point for the demo, the cell, the studies and benches.

Each sub-command imports what it needs lazily, so ``pointforce --help`` is instant and the core
sub-commands run without a ROS graph.
"""

import argparse
import contextlib
import importlib
import json
import os
import sys
from pathlib import Path
from typing import Callable, Dict, List, Optional

import yaml

from pointforce_ros import arguments
from pointforce_ros.dds import use_package_dds_profile
from pointforce_ros.errors import PointforceError, reading, TEXT_ENCODING
from pointforce_ros.replica import cli as replica_cli

BENCHMARKS: Dict[str, str] = {
    'contact': 'pointforce_ros.lab.bench_contact:bench_contact',
    'batch': 'pointforce_ros.lab.bench_contact:bench_batch',
    'learn': 'pointforce_ros.lab.bench_learn:bench_learn',
    'calibrate': 'pointforce_ros.lab.bench_calibrate:bench_calibrate',
    'cell': 'pointforce_ros.sim.fem.bench:bench_cell',
    'ros': 'pointforce_ros.bringup.bench_ros:bench_ros',
    'deformation': 'pointforce_ros.deformation.bench:bench_deformation',
    'faults': 'pointforce_ros.bringup.bench_faults:bench_faults',
    'streams': 'pointforce_ros.bringup.bench_streams:bench_streams',
}


QUICK: Dict[str, dict] = {'cell': {'queries': 200, 'full_solve': False},
                          'deformation': {'baseline': False}}
"""Keyword arguments of ``--quick`` per benchmark (default ``{'quick': True}``)."""


def _load(target: str) -> Callable:
    module, _, name = target.partition(':')
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise PointforceError(f'{target} is not available in this build: {exc}') from exc


@contextlib.contextmanager
def _stdout_to_stderr():
    """Send everything written to file descriptor 1 to 2 inside (libraries' prints too).

    ``--json`` promises one JSON object per line on stdout; ur_rtde's C++ prints
    ("Reconnecting...") and rclpy's would otherwise land between them.
    """
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _cmd_bench(args) -> int:
    names = list(BENCHMARKS) if args.name == 'all' else [args.name]
    for name in names:
        kwargs = QUICK.get(name, {'quick': True}) if args.quick else {}
        with _stdout_to_stderr() if args.json else contextlib.nullcontext():
            result = _load(BENCHMARKS[name])(**kwargs)
        result = {'benchmark': name, **result}
        if args.json:
            print(json.dumps(result, sort_keys=True))
        else:
            print(f'== bench {name}')
            for key, value in result.items():
                print(f'  {key:40s} {value}')
    return 0


def _domain_id(text: str) -> int:
    """Parse a ROS domain id (0-232) for argparse."""
    value = int(text)
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f'{value} is outside 0-232')
    return value


def _decay_law(text: str) -> str:
    """Parse a shape-function decay law for argparse (the simulator's names)."""
    try:
        return _load('pointforce_ros.contact.simulator:check_decay_law')(text, 'law')
    except PointforceError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


def _check_simulation(object_name: Optional[str], scenario: Optional[str]) -> None:
    """Load the simulated object and scenario a command names, before any work starts.

    Raises:
        PointforceError: an unknown name or an invalid file (the message names it and the
            known ones), in a second rather than after the cell or the emulator has started.

    """
    if object_name is not None:
        _load('pointforce_ros.sim.objects:load_object')(object_name)
    if scenario is not None:
        _load('pointforce_ros.sim.scenario:load_scenario')(scenario)


def _cmd_demo(args) -> int:
    analytic = args.object == _load('pointforce_ros.bringup.cell:SIM_OBJECT_HALFSPACE')
    _check_simulation(None if analytic else args.object, args.scenario)
    return _load('pointforce_ros.bringup.demo:run_demo')(
        out=args.out, quick=args.quick, object_name=args.object, scenario=args.scenario,
        pokes=args.pokes, camera_check=args.camera_check, domain=args.domain,
        decay_law=args.decay_law)


NODES = ('cloud_capture', 'poke_server', 'stiffness_learner', 'contact_wrench',
         'deformation_force')
"""The product nodes a parameter file may configure."""


def check_params_file(path) -> str:
    """Return the absolute path of a ROS parameter file for the cell's nodes, checked.

    Keys are node names, plain or with a namespace wildcard (``/**/contact_wrench``), each with
    ``ros__parameters``.

    Raises:
        PointforceError: no such file, not YAML, or a section that names no product node.

    """
    path = Path(path).expanduser().resolve()
    with reading(f'--params-file {path}', 'parameter file (YAML)'):
        content = yaml.safe_load(path.read_text(encoding=TEXT_ENCODING))
    if not isinstance(content, dict) or not content:
        raise PointforceError(f'--params-file {path}: not a mapping of node names')
    for key, section in content.items():
        name = str(key).rsplit('/', 1)[-1]
        if name not in NODES and name not in ('*', '**'):
            raise PointforceError(f'--params-file {path}: section {key!r} names no node of the '
                                  f'cell ({", ".join(NODES)})')
        if not isinstance(section, dict) or 'ros__parameters' not in section:
            raise PointforceError(f'--params-file {path}: section {key!r} has no '
                                  'ros__parameters')
    return str(path)


def _cmd_cell(args) -> int:
    if args.action == 'generate':
        _check_simulation(args.object, args.scenario)      # before the --out folder is made
        return _load('pointforce_ros.sim.generate:run_generate')(
            object_name=args.object, scenario=args.scenario, pokes=args.pokes,
            probes=[p for p in args.probes.split(',') if p], seed=args.seed,
            out=args.out or f'out/data/{args.object}-{args.scenario}')
    if args.duration is not None and not args.duration >= 0:     # 0: start, then stop
        raise PointforceError(f'--duration must be >= 0 s (or left out: run until Ctrl-C), '
                              f'got {args.duration}')
    params_file = check_params_file(args.params_file) if args.params_file else None
    if args.robot_ip is None:       # the emulator's scenario, refused with one line
        _check_simulation(None, args.scenario)
    return _load('pointforce_ros.bringup.cell:run_cell')(
        out=args.out or 'out/cell', object_name=args.object, scenario=args.scenario,
        robot_ip=args.robot_ip, camera_topic=args.camera_topic, duration=args.duration,
        params_file=params_file)


def _cmd_diagnose(args) -> int:
    run = _load('pointforce_ros.diagnose.run:run_diagnose')
    return run(args.data, args.out, seed=args.seed, json_out=args.json)


def _cmd_figures(args) -> int:
    return _load('pointforce_ros.lab.figures:main')(args.rest)


def _cmd_deformation(args) -> int:
    return _load('pointforce_ros.lab.deformation_figures:main')(args.rest)


def _cmd_health(args) -> int:
    return _load('pointforce_ros.bringup.health:run_health')(args.wait, json_out=args.json)


def _cmd_replay(args) -> int:
    return _load('pointforce_ros.bringup.replay:run_replay')(args.bag, rate=args.rate)


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of the ``pointforce`` command."""
    parser = argparse.ArgumentParser(prog='pointforce',
                                     description=__doc__.splitlines()[0].replace('``', ''))
    sub = parser.add_subparsers(dest='command', required=True)

    demo = sub.add_parser('demo', help='run the whole job on the simulated cell')
    demo.add_argument('--out', default='out/demo', help='output directory (bags, model, plots)')
    demo.add_argument('--quick', action='store_true', help='fewer pokes (4 instead of 8)')
    demo.add_argument('--object', default='lamb', help='simulated object (config/objects)')
    demo.add_argument('--scenario', default='realistic', help='sensor effects (config/scenarios)')
    demo.add_argument('--pokes', type=arguments.poke_count, default=0,
                      help=f'number of pokes (0: 8, or 4 quick; at most {arguments.MAX_POKES})')
    demo.add_argument('--camera-check', action='store_true',
                      help='also estimate one contact force from the camera alone against the '
                           'F/T (seed 001; two ground-truth FEM solves, about 5 min more)')
    demo.add_argument('--domain', type=_domain_id, default=None,
                      help='ROS domain of the simulated cell (default: one of its own, '
                           'localhost only, so it never meets a real cell or another run)')
    demo.add_argument('--decay-law', type=_decay_law, default=None,
                      help="the learner's shape_decay_law (fixed, penetration or layer; "
                           'default: its own), under which (c, L) are identified and served')
    demo.set_defaults(func=_cmd_demo)

    cell = sub.add_parser('cell', help='run the node suite on the simulated (or a real) cell; '
                          '"cell generate" writes data sets')
    cell.add_argument('action', nargs='?', choices=['run', 'generate'], default='run',
                      help='run the cell (default) or generate a data set')
    cell.add_argument('--object', default='lamb', help='simulated object (config/objects)')
    cell.add_argument('--scenario', default='realistic',
                      help='simulated sensor effects (config/scenarios)')
    cell.add_argument('--robot-ip', default=None, help='a real UR controller (no emulator)')
    cell.add_argument('--camera-topic', default=None,
                      help='a real PointCloud2 topic (no simulated camera)')
    cell.add_argument('--params-file', default=None,
                      help='ROS parameter file of the five nodes (config/nodes.yaml); the '
                      'cell\'s own settings (output paths, --robot-ip, --camera-topic, the '
                      'simulated object\'s ROI) win over it')
    cell.add_argument('--out', default=None, help='output directory')
    cell.add_argument('--duration', type=float, default=None, help='seconds to run (run)')
    cell.add_argument('--pokes', type=arguments.poke_count, default=20,
                      help=f'point pokes (generate; at most {arguments.MAX_POKES})')
    cell.add_argument('--probes', default='point,line,cylinder',
                      help='probe kinds to generate, comma-separated (generate)')
    cell.add_argument('--seed', type=arguments.seed, default=0, help='seed (generate)')
    cell.set_defaults(func=_cmd_cell)

    diagnose = sub.add_parser('diagnose', help='residuals -> the physical effect behind them, '
                              'error before and after (held-out)')
    diagnose.add_argument('data', help='poke store directory, one poke bag, or a CSV table')
    diagnose.add_argument('--out', default='out/diagnose', help='report directory')
    diagnose.add_argument('--seed', type=arguments.seed, default=0,
                          help='train/held-out split seed')
    diagnose.add_argument('--json', action='store_true',
                          help='print the JSON summary on stdout (progress on stderr)')
    diagnose.set_defaults(func=_cmd_diagnose)

    replica_cli.add_parser(sub)

    figures = sub.add_parser('figures', help='the seed-method figures on the simulated cell '
                             '(learning curves, probe wrench RMSE, shape constant)')
    figures.add_argument('rest', nargs=argparse.REMAINDER,
                         help='options of python -m pointforce_ros.lab.figures (--out, --quick, '
                         '...)')
    figures.set_defaults(func=_cmd_figures)

    deformation = sub.add_parser('deformation', help='seed 001 on the simulated cell: (E, nu) '
                                 'identification and force from the camera, against the truth')
    deformation.add_argument('rest', nargs=argparse.REMAINDER,
                             help='options of python -m pointforce_ros.lab.deformation_figures '
                             '(--object, --json, ...)')
    deformation.set_defaults(func=_cmd_deformation)

    replay = sub.add_parser('replay', help='republish a rosbag2 MCAP bag (or a poke store)')
    replay.add_argument('bag', help='bag directory, .mcap file, or poke store directory')
    replay.add_argument('--rate', type=arguments.replay_rate, default=1.0,
                        help='speed-up factor (1 = real time; at least '
                        f'{arguments.MIN_REPLAY_RATE:g})')
    replay.set_defaults(func=_cmd_replay)

    health = sub.add_parser('health', help="the running cell's nodes' /diagnostics reports "
                            '(exit 0 all OK, 1 a warning, 2 an error, 3 none heard)')
    health.add_argument('--wait', type=float, default=3.0,
                        help='seconds to listen (the nodes report once a second)')
    health.add_argument('--json', action='store_true', help='one JSON object with the values')
    health.set_defaults(func=_cmd_health)

    bench = sub.add_parser('bench', help='benchmarks; ratios against a baseline in the same run')
    bench.add_argument('name', choices=sorted(BENCHMARKS) + ['all'])
    bench.add_argument('--json', action='store_true', help='one JSON object per benchmark')
    bench.add_argument('--quick', action='store_true', help='smaller sizes (for CI smoke)')
    bench.set_defaults(func=_cmd_bench)
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of the ``pointforce`` console script."""
    argv = sys.argv[1:] if argv is None else list(argv)
    forward = {'figures': _cmd_figures, 'deformation': _cmd_deformation}
    if argv and argv[0] in forward:
        # options of the lab modules go to them untouched: argparse's REMAINDER would refuse
        # one in first place ("pointforce figures --out DIR")
        args = argparse.Namespace(command=argv[0], rest=argv[1:], func=forward[argv[0]])
    else:
        args = build_parser().parse_args(argv)
    # before any rclpy.init: the demo and the benches call the contact service as a planner
    # does; the cell hosts nodes
    use_package_dds_profile(kind='planner' if args.command in ('demo', 'bench') else 'node')
    try:
        return int(args.func(args) or 0)
    except PointforceError as exc:
        print(f'pointforce {args.command}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'pointforce {args.command}: interrupted', file=sys.stderr)
        return 130
    except OSError as exc:      # a path the user gave: a file for a folder, no permission, ...
        print(f'pointforce {args.command}: error: {type(exc).__name__}: {exc}', file=sys.stderr)
        return 2
    except MemoryError as exc:  # numpy refusing an allocation: a size the bounds let through
        print(f'pointforce {args.command}: error: out of memory: {exc or "MemoryError"}; ask '
              'for a smaller problem', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
