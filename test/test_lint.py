"""flake8 (99 columns, ament defaults) and pep257 docstrings, as tests."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ['pointforce_ros', 'msg_adapters', 'test', 'launch', 'setup.py']


def _run(args):
    return subprocess.run([sys.executable, '-m'] + args, cwd=ROOT, capture_output=True, text=True)


def test_flake8():
    result = _run(['flake8', '--max-line-length', '99'] + SOURCES)
    assert result.returncode == 0, 'flake8 found problems:\n' + result.stdout + result.stderr


def test_pep257():
    # ament_pep257 defaults; test files are exempt from docstring rules as in ament_pep257
    result = _run(['pydocstyle', '--convention=pep257',
                   '--add-ignore=D100,D104,D105,D107,D203,D212,D404',
                   'pointforce_ros', 'msg_adapters'])
    assert result.returncode == 0, 'pep257 found problems:\n' + result.stdout + result.stderr
