"""The ``pointforce`` command line: every benchmark it names exists and takes its arguments."""

import inspect
import json
import subprocess
import sys
import textwrap

import pytest

from pointforce_ros.bringup import cli
from pointforce_ros.dds import PROFILE_VARIABLES
from pointforce_ros.lab import step_data


@pytest.mark.parametrize('name', sorted(cli.BENCHMARKS))
def test_every_benchmark_resolves_and_accepts_its_quick_arguments(name):
    func = cli._load(cli.BENCHMARKS[name])
    signature = inspect.signature(func)
    signature.bind()                                              # the full run
    signature.bind(**cli.QUICK.get(name, {'quick': True}))        # --quick


def test_unknown_target_is_a_clear_error():
    with pytest.raises(cli.PointforceError, match='not available in this build'):
        cli._load('pointforce_ros.no_such_module:bench')


def test_bench_json_keeps_stdout_to_the_json_lines_when_a_library_prints():
    # a benchmark whose library writes to file descriptor 1 itself (ur_rtde's C++ prints
    # "Reconnecting..." there), run as `pointforce bench NAME --json` would run it
    code = textwrap.dedent('''
        import os
        from pointforce_ros.bringup import cli

        def noisy(quick=False):
            os.write(1, b'Reconnecting...\\n')
            print('and a Python print')
            return {'value': 1.5}

        cli.BENCHMARKS['noisy'] = '__main__:noisy'
        args = cli.build_parser().parse_args(['bench', 'contact', '--json'])
        args.name = 'noisy'
        raise SystemExit(cli._cmd_bench(args))
    ''')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert [json.loads(line) for line in out.stdout.splitlines()] == [
        {'benchmark': 'noisy', 'value': 1.5}]
    assert 'Reconnecting...' in out.stderr and 'and a Python print' in out.stderr


def test_figures_and_deformation_pass_their_options_on(tmp_path, capsys, monkeypatch):
    for name in PROFILE_VARIABLES:            # main names a DDS profile: undone after the test
        monkeypatch.setenv(name, '')
    # an option in first place reaches the lab module (argparse's REMAINDER refused it)
    assert cli.main(['figures', '--objects', 'no_such_object', '--out', str(tmp_path)]) == 2
    assert "unknown object(s) ['no_such_object']" in capsys.readouterr().out
    assert cli.main(['deformation', '--object', 'no_such_object']) == 2
    assert "no deformation fixtures for 'no_such_object'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize('duration', ['-5', '-0.5', 'nan'])
def test_a_negative_cell_duration_is_refused(duration, capsys, monkeypatch):
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    assert cli.main(['cell', 'run', '--duration', duration]) == 2
    assert '--duration must be >= 0 s' in capsys.readouterr().err


def _refused_in_a_process(argv, cwd) -> str:
    """Run ``pointforce argv`` in its own process; assert status 2, no traceback; stderr."""
    code = f'import sys; from pointforce_ros.bringup.cli import main; sys.exit(main({argv!r}))'
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120, cwd=cwd)
    assert out.returncode == 2, out.stderr
    assert 'Traceback' not in out.stderr
    return out.stderr


def test_a_path_that_cannot_be_used_is_an_error_line_not_a_traceback(tmp_path):
    a_file = tmp_path / 'notes.txt'
    a_file.write_text('not a folder')
    err = _refused_in_a_process(['cell', 'generate', '--pokes', '1', '--out',
                                 f'{a_file}/data'], tmp_path)
    assert 'pointforce cell: error: NotADirectoryError' in err


def test_the_cell_names_a_parameter_file_value_a_node_refuses(tmp_path):
    # before: rclpy's InvalidParameterValueException as a traceback, the emulator left to
    # the cell's cleanup
    params = tmp_path / 'nodes.yaml'
    params.write_text('/**/poke_server:\n  ros__parameters:\n    max_force: -5.0\n')
    err = _refused_in_a_process(['cell', 'run', '--params-file', str(params), '--duration',
                                 '0', '--out', 'cell'], tmp_path)
    assert 'pointforce cell: error: a node of the cell refused its parameters' in err
    assert 'max_force out of range' in err


@pytest.mark.parametrize('argv, message', [
    (['demo', '--pokes', '-1'], 'argument --pokes: -1 is not in 0..1000'),
    (['demo', '--decay-law', 'depth'], "argument --decay-law: law: must be one of ('fixed',"),
    (['cell', 'generate', '--seed', '-1'], 'argument --seed: -1 is not in 0..4294967295'),
    (['cell', 'generate', '--pokes', 'many'], "argument --pokes: 'many' is not a whole number"),
    (['diagnose', 'x.csv', '--seed', str(2 ** 32)], 'argument --seed: 4294967296 is not in'),
    (['replay', 'x', '--rate', 'inf'], 'argument --rate: inf is not a finite number >= 0.001'),
    (['replica', '--data', 'x', '--out', 'y', '--h', '-0.01'],
     'argument --h: -0.01 is not a finite number > 0'),
    (['replica', '--data', 'x', '--out', 'y', '--train', '0'], 'argument --train: 0 is not >= 1'),
    (['figures', '--repeats', '0'], 'argument --repeats: 0 is not >= 1'),
    (['figures', '--sizes', '5', '0'], 'argument --sizes: 0 is not >= 1'),
    (['figures', '--auto-budget', 'nan'], 'argument --auto-budget: nan is not a finite number'),
    (['deformation', '--element-size', '-1'], 'argument --element-size: -1.0 is not a finite'),
    (['deformation', '--layers', '0'], 'argument --layers: 0 is not >= 1'),
    (['deformation', '--identify-depth', 'nan'], 'argument --identify-depth: nan is not a'),
])
def test_a_number_outside_its_range_is_refused_before_anything_runs(
        argv, message, capsys, monkeypatch):
    # before: --pokes -1 started the cell and ended in an UnboundLocalError, --seed -1 in
    # numpy's ValueError, --repeats 0 ran the default 10, --element-size -1 printed FAILED for
    # every object and exited 0
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 2
    assert message in capsys.readouterr().err


def test_a_params_file_that_is_not_text_is_one_error_line(tmp_path, capsys, monkeypatch):
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    params = tmp_path / 'nodes.yaml'
    params.write_bytes(b'\xac\xed\x00\x05binary')
    assert cli.main(['cell', 'run', '--params-file', str(params), '--duration', '0']) == 2
    err = capsys.readouterr().err
    assert 'unreadable parameter file (YAML): UnicodeDecodeError' in err
    assert str(params) in err


@pytest.mark.parametrize('argv, message', [
    (['demo', '--pokes', '1000000000'], 'argument --pokes: 1000000000 is not in 0..1000'),
    (['cell', 'generate', '--pokes', '1001'], 'argument --pokes: 1001 is not in 0..1000'),
    (['replay', 'no_such_bag', '--rate', '1e-300'],
     'argument --rate: 1e-300 is not a finite number >= 0.001'),
])
def test_a_poke_count_or_replay_rate_past_its_bound_is_refused_as_it_is_parsed(
        argv, message, capsys, monkeypatch):
    # before: cell generate --pokes 1e9 drew 10^9 locations (15 GB in 40 s), the demo started
    # a campaign of 10^9 pokes, --rate 1e-300 failed in the replay on time_t overflow; an
    # unknown object makes the old code stop in seconds instead of running
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    with pytest.raises(SystemExit) as info:
        cli.main(argv + (['--object', 'no_such_object'] if argv[0] != 'replay' else []))
    assert info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize('option, message', [
    (['--h', '1e-6'], '--h 1e-06 m is below 0.001 m'),
    (['--paper-grid', '100000000'], '--paper-grid must be in 2..10'),
])
def test_a_replica_mesh_or_grid_past_its_bound_is_refused_before_the_data_is_read(
        tmp_path, option, message, capsys, monkeypatch):
    # before: --h 1e-6 ended in numpy's MemoryError traceback (36 GiB asked), --paper-grid 1e8
    # took 9 GB within a minute
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    code = cli.main(['replica', '--data', str(tmp_path / 'no_such_pokes'), '--out',
                     str(tmp_path / 'replica')] + option)
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'replica').exists()


@pytest.mark.parametrize('option', [['--scenario', 'no_such_scenario'],
                                    ['--object', 'no_such_object']])
def test_cell_generate_with_an_unknown_name_makes_no_output_folder(
        tmp_path, option, capsys, monkeypatch):
    # before: the --out folder was made, then the name refused: an empty folder left behind
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    out = tmp_path / 'data'
    assert cli.main(['cell', 'generate', '--pokes', '1', '--out', str(out)] + option) == 2
    assert f"'{option[1]}'" in capsys.readouterr().err
    assert not out.exists()


def test_a_cell_with_an_unknown_scenario_is_one_error_line(tmp_path, capsys, monkeypatch):
    # before: the emulator started, exited, and its stderr followed on further lines
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    assert cli.main(['cell', 'run', '--scenario', 'no_such_scenario', '--duration', '0',
                     '--out', str(tmp_path / 'cell')]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pointforce cell: error: unknown scenario 'no_such_scenario'; known:")
    assert err.count('\n') == 1
    assert not (tmp_path / 'cell').exists()


def test_diagnose_refuses_an_out_that_is_a_file_before_the_analysis(
        tmp_path, capsys, monkeypatch):
    # before: the whole diagnosis ran (minutes on a real store), then FileExistsError
    for name in PROFILE_VARIABLES:
        monkeypatch.setenv(name, '')
    table = step_data.make_step_table(tmp_path / 'steps.csv', pokes=4, seed=3)['path']
    report = tmp_path / 'report.md'
    report.write_text('an earlier report')
    for out in (report, report / 'sub'):
        assert cli.main(['diagnose', str(table), '--out', str(out)]) == 2
        captured = capsys.readouterr()
        assert captured.out == ''                                 # no analysis progress
        assert f'--out {out}: {report} is a file, not a folder' in captured.err
    assert report.read_text() == 'an earlier report'


@pytest.mark.parametrize('argv, message', [
    (['--seed', '-1'], 'argument --seed: -1 is not in 0..4294967295'),
    (['--pokes', '4', '--score', '4'], 'argument --score: 4 leaves no held-out poke'),
    (['--per-poke', '0'], 'argument --per-poke: 0 is not >= 1'),
])
def test_step_data_refuses_a_bad_argument_as_argparse_does(tmp_path, argv, message, capsys):
    # before: numpy's ValueError (seed), InvalidInput after the table was made (score)
    with pytest.raises(SystemExit) as info:
        step_data.main(['--out', str(tmp_path / 'steps.csv')] + argv)
    assert info.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / 'steps.csv').exists()


@pytest.mark.parametrize('case', ['object', 'out_is_a_folder', 'per_poke'])
def test_step_data_names_a_bad_object_or_out_in_one_line(tmp_path, case, capsys):
    # before: a DataError, IsADirectoryError or numpy MemoryError traceback
    argv = {'object': ['--out', str(tmp_path / 's.csv'), '--object', 'no_such_object'],
            'out_is_a_folder': ['--out', str(tmp_path), '--pokes', '2'],
            'per_poke': ['--out', str(tmp_path / 's.csv'), '--per-poke', '100000000']}[case]
    assert step_data.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err
    assert {'object': "object 'no_such_object' not found", 'out_is_a_folder': 'IsADirectoryError',
            'per_poke': 'per_poke in 2..1000'}[case] in err
