"""The ``pointforce`` command line: every benchmark it names exists and takes its arguments."""

import inspect

import pytest

from pointforce_ros.bringup import cli


@pytest.mark.parametrize('name', sorted(cli.BENCHMARKS))
def test_every_benchmark_resolves_and_accepts_its_quick_arguments(name):
    func = cli._load(cli.BENCHMARKS[name])
    signature = inspect.signature(func)
    signature.bind()                                              # the full run
    signature.bind(**cli.QUICK.get(name, {'quick': True}))        # --quick


def test_unknown_target_is_a_clear_error():
    with pytest.raises(cli.PointforceError, match='not available in this build'):
        cli._load('pointforce_ros.no_such_module:bench')
