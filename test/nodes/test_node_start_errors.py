"""What a node says when its command line or its folders cannot work (a user's typo).

* a parameter file rcl cannot parse ends the node with rcl's reason and status 2, no traceback
  (both start paths: ``run`` and the contact node's single-threaded spin), and so does a
  configuration a node refuses before it serves (a poke store that is a file, a parameter out
  of its range or of another type, a camera pose that is no pose, a topic name that is not
  valid) (the simulated cell's case: ``test/bringup/test_cli.py``);
* a folder parameter that names a file is an error in the log at start, and a polled folder
  that does not exist yet a warning; the node still comes up.
"""

import subprocess
import sys

import pytest
import rclpy
from rclpy.parameter import Parameter

from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.deformation_force import DeformationForceNode
from pointforce_ros.nodes.stiffness_learner import StiffnessLearnerNode

pytestmark = pytest.mark.ros


def _refused_node(module: str, ros_args, cwd) -> str:
    """Start node ``module`` with ``--ros-args ros_args``; assert status 2, no traceback."""
    out = subprocess.run([sys.executable, '-m', f'pointforce_ros.nodes.{module}', '--ros-args',
                          *ros_args], capture_output=True, text=True, timeout=60, cwd=cwd)
    assert out.returncode == 2, out.stderr
    assert 'Traceback' not in out.stderr
    return out.stderr


@pytest.mark.parametrize('module', ['contact_wrench', 'stiffness_learner'])
def test_a_params_file_rcl_cannot_parse_ends_the_node_with_its_reason(tmp_path, module):
    bad = tmp_path / 'nodes.yaml'
    bad.write_text('/**/contact_wrench: [ros__parameters\n')
    err = _refused_node(module, ['--params-file', str(bad)], tmp_path)
    assert 'cannot start' in err and "Couldn't parse params file" in err


def test_a_configuration_a_node_refuses_ends_it_with_the_reason(tmp_path):
    a_file = tmp_path / 'pokes.txt'
    a_file.write_text('not a folder')
    err = _refused_node('poke_server', ['-p', f'store_dir:={a_file}'], tmp_path)
    assert f'cannot start: poke store {a_file} is a file' in err


@pytest.mark.parametrize('module, argument, reason', [
    ('poke_server', 'max_force:=-5.0', 'Parameter max_force out of range Min: 0.1'),
    ('contact_wrench', 'max_batch:=many', "Trying to set parameter 'max_batch' to 'many'"),
    ('cloud_capture', 'camera_pose:=[0.5,0.0,0.5,0.0,0.0,0.0,0.0]',
     'camera_pose: Pose.orientation: quaternion must be unit length'),
    ('deformation_force', 'camera_pose:=[1.0]', 'camera_pose: Pose.position: expected shape'),
    ('cloud_capture', 'cloud_topic:=a b', 'Invalid topic name'),
    ('stiffness_learner', 'point_spread:=forest',
     "point_spread: must be one of ('gp', 'trees', 'mix')"),
])
def test_a_parameter_a_node_refuses_ends_it_with_the_reason(tmp_path, module, argument, reason):
    # before: rclpy's InvalidParameterValueException / TypeException, or the node's own
    # ValueError, as a traceback with status 1
    err = _refused_node(module, ['-p', argument], tmp_path)
    assert 'cannot start' in err and reason in err, err


@pytest.fixture
def context(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)     # the learner's default out/ folders land here
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_folder_parameters_that_cannot_work_are_reported_at_start(tmp_path, context, capfd):
    a_file = tmp_path / 'models.txt'
    a_file.write_text('not a folder')
    node = ContactWrenchNode(context=context,
                             parameter_overrides=[Parameter('model_dir', value=str(a_file))])
    node.destroy_node()
    assert f'model_dir {a_file} is a file, not a folder' in capfd.readouterr().err
    later = tmp_path / 'not_yet'
    node = ContactWrenchNode(context=context,
                             parameter_overrides=[Parameter('model_dir', value=str(later))])
    node.destroy_node()
    assert f'model_dir {later} does not exist yet: polling it' in capfd.readouterr().err
    node = StiffnessLearnerNode(context=context,
                                parameter_overrides=[Parameter('store_dir', value=str(a_file))])
    node.destroy_node()
    err = capfd.readouterr().err
    assert f'store_dir {a_file} is a file, not a folder' in err and 'model_dir' not in err
    node = DeformationForceNode(context=context, parameter_overrides=[
        Parameter('model_dir', value=str(a_file)), Parameter('point_model_dir', value='')])
    node.destroy_node()
    err = capfd.readouterr().err
    assert f'model_dir {a_file} is a file, not a folder' in err and 'point_model_dir' not in err
