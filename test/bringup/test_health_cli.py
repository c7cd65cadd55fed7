"""``pointforce health``: the running nodes' /diagnostics as a table, exit code by the worst."""

import json
import os
import subprocess
import sys

import pytest
from rclpy.parameter import Parameter

from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode

pytestmark = pytest.mark.ros
NAME = 'contact_wrench: contact service'


def _health(*args, env=None):
    return subprocess.run([sys.executable, '-m', 'pointforce_ros.bringup.cli', 'health', *args],
                          capture_output=True, text=True, timeout=120, env=env)


def test_health_prints_each_nodes_newest_report_and_exits_by_the_worst(ros_graph, tmp_path):
    node = ros_graph.add(ContactWrenchNode(
        context=ros_graph.context,
        parameter_overrides=[Parameter('model_dir', value=str(tmp_path / 'models')),
                             Parameter('poll_period', value=0.1)]))
    out = _health('--wait', '2.5', '--json')       # no model: every request would be refused
    assert out.returncode == 2, (out.stdout, out.stderr)
    report = json.loads(out.stdout)
    assert report['worst'] == 'ERROR'
    assert report['reports'][NAME]['level'] == 2
    assert 'no contact model' in report['reports'][NAME]['message']
    assert report['reports'][NAME]['values']['model_version'] == '-1'
    model = patch_contact_model(spacing=0.003)
    save_model(model, tmp_path / 'models')
    ros_graph.wait_for(lambda: node.server.version == model.version, 10, 'model loaded')
    out = _health('--wait', '2.5')
    assert out.returncode == 0, (out.stdout, out.stderr)
    line = next(row for row in out.stdout.splitlines() if NAME in row)
    assert line.startswith('OK ') and f'serving model v{model.version}' in line


def test_health_says_when_no_node_reports_and_refuses_a_bad_wait():
    other = (int(os.environ['ROS_DOMAIN_ID']) % 100) + 1      # no node of this run there
    out = _health('--wait', '1.5', env=dict(os.environ, ROS_DOMAIN_ID=str(other)))
    assert out.returncode == 3 and 'no /diagnostics report' in out.stdout, out.stdout
    bad = _health('--wait', '-1')
    assert bad.returncode == 2 and '--wait must be in' in bad.stderr
