"""The package's Fast DDS profile: found, named unless the user names one, accepted by Fast DDS."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pointforce_ros.dds import package_dds_profile, PROFILE_VARIABLES, use_package_dds_profile

START_NODE = ("import rclpy; rclpy.init(); from rclpy.node import Node; Node('profile_check'); "
              "print('node up')")


def _start_a_node(profile: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in PROFILE_VARIABLES}
    env[PROFILE_VARIABLES[0]] = str(profile)
    return subprocess.run([sys.executable, '-c', START_NODE], env=env, capture_output=True,
                          text=True, timeout=60)


def test_the_package_profile_is_named_unless_the_user_names_one():
    planner = {}
    assert use_package_dds_profile(planner, kind='planner').endswith('fastdds_planner.xml')
    # a node started by a planner process gets the nodes' profile, not the planner's
    assert use_package_dds_profile(planner).endswith('config/fastdds.xml')
    assert list(planner.values()) == [package_dds_profile('node')]
    env = {}
    path = use_package_dds_profile(env)
    assert path is not None and Path(path).is_file() and path.endswith('config/fastdds.xml')
    assert env == {PROFILE_VARIABLES[0]: path}
    mine = {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/my_cell/dds.xml'}
    assert use_package_dds_profile(mine) == '/etc/my_cell/dds.xml'
    assert mine == {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/my_cell/dds.xml'}
    newer = {'FASTDDS_DEFAULT_PROFILES_FILE': '/etc/my_cell/dds.xml'}
    assert use_package_dds_profile(newer) == '/etc/my_cell/dds.xml' and len(newer) == 1


@pytest.mark.parametrize('kind', ['node', 'planner'])
def test_fast_dds_parses_the_profile_and_reports_a_broken_one(tmp_path, kind):
    path = Path(package_dds_profile(kind))
    run = _start_a_node(path)
    said = run.stdout + run.stderr          # Fast DDS logs its parser errors on stdout
    assert run.returncode == 0 and 'node up' in said, said
    assert 'XMLPARSER' not in said and 'Error' not in said, said
    # the check can fail: the same profile with a malformed duration is reported
    broken = tmp_path / 'broken.xml'
    broken.write_text(path.read_text().replace('<sec>5</sec>', '<sec>five</sec>'))
    run = _start_a_node(broken)
    said = run.stdout + run.stderr
    assert 'XMLPARSER' in said and 'leaseDuration' in said, said
