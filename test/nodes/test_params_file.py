"""The real cell's set-up files: launch/cell.launch.py and config/nodes.yaml (issue 21).

There is no launch wheel here, so the launch file is checked for what it must say (parsed with
``ast``, not run). The parameter file is checked against the nodes themselves: every key is a
declared parameter of its node, with a value the node accepts, and every declared parameter is in
the file; rcl itself loads it into a namespaced node.
"""

import ast
from pathlib import Path

import pytest
import rclpy
import yaml
from rclpy.parameter import Parameter

from pointforce_ros.nodes.cloud_capture import CloudCaptureNode
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.deformation_force import DeformationForceNode
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.stiffness_learner import StiffnessLearnerNode

from idle_arm import IdleArm  # noqa: I100 - the test helper beside this file

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / 'config' / 'nodes.yaml'
LAUNCH = ROOT / 'launch' / 'cell.launch.py'
BUILT_IN = {'use_sim_time', 'start_type_description_service'}
"""Parameters rclpy declares on every node."""


NODES = {'cloud_capture': (CloudCaptureNode, {}),
         'poke_server': (PokeServerNode, {'arm_factory': IdleArm}),
         'stiffness_learner': (StiffnessLearnerNode, {}),
         'contact_wrench': (ContactWrenchNode, {}),
         'deformation_force': (DeformationForceNode, {})}   # issue 18: was missing


def _file_params():
    content = yaml.safe_load(PARAMS.read_text())
    out = {}
    for key, section in content.items():
        assert key.startswith('/**/'), f'{key}: use /**/<node> so a namespaced node matches'
        out[key[len('/**/'):]] = section['ros__parameters']
    return out


@pytest.fixture
def context(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)     # the defaults' relative out/ directories land here
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_the_parameter_file_holds_exactly_each_nodes_declared_parameters(context):
    params = _file_params()
    assert set(params) == set(NODES)
    for name, (cls, kwargs) in NODES.items():
        values = params[name]
        node = cls(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()], **kwargs)
        try:
            declared = set(node._parameters) - BUILT_IN
            assert set(values) - declared == set(), f'{name}: keys it does not declare'
            assert declared - set(values) == set(), f'{name}: parameters missing from the file'
            for key, value in values.items():
                assert node.get_parameter(key).value == pytest.approx(value), (name, key)
        finally:
            node.destroy_node()


def test_rcl_loads_the_file_into_a_namespaced_node(context, tmp_path):
    content = yaml.safe_load(PARAMS.read_text())
    content['/**/contact_wrench']['ros__parameters']['max_batch'] = 123
    edited = tmp_path / 'nodes.yaml'
    edited.write_text(yaml.safe_dump(content))
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=['--ros-args', '--params-file', str(edited)])
    try:
        node = ContactWrenchNode(context=ctx, namespace='/cell1')
        assert node.get_parameter('max_batch').value == 123
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_the_launch_file_starts_the_five_nodes_with_the_parameter_file():
    tree = ast.parse(LAUNCH.read_text(), filename=str(LAUNCH))
    functions = {f.name for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)}
    assert 'generate_launch_description' in functions
    imports = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
               for a in n.names}
    assert ('launch_ros.actions', 'Node') in imports and ('launch', 'LaunchDescription') in imports
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
               and isinstance(n.value, str)}
    assert set(NODES) <= strings                        # the five executables
    executables, = [ast.literal_eval(n.value) for n in ast.walk(tree)
                    if isinstance(n, ast.Assign) and getattr(n.targets[0], 'id', '') ==
                    'EXECUTABLES']
    assert sorted(executables) == sorted(NODES)        # each started, none twice
    assert {'nodes.yaml', 'params_file', 'robot_ip', 'cloud_topic', 'namespace',
            'pointforce_ros'} <= strings
    launch_args = {call.args[0].value for call in ast.walk(tree)
                   if isinstance(call, ast.Call) and getattr(call.func, 'id', '') ==
                   'DeclareLaunchArgument'}
    assert launch_args == {'params_file', 'namespace', 'robot_ip', 'cloud_topic',
                           'contact_workers'}
    node_calls = [call for call in ast.walk(tree) if isinstance(call, ast.Call)
                  and getattr(call.func, 'id', '') == 'Node']
    assert node_calls and {'package', 'executable', 'namespace', 'parameters'} <= {
        k.arg for k in node_calls[0].keywords}


def test_a_launched_contact_worker_gets_the_files_contact_wrench_parameters(context):
    tree = ast.parse(LAUNCH.read_text(), filename=str(LAUNCH))
    function, = [f for f in tree.body if isinstance(f, ast.FunctionDef)
                 and f.name == '_contact_parameters']
    namespace = {'yaml': yaml}
    exec(compile(ast.Module(body=[function], type_ignores=[]), str(LAUNCH), 'exec'), namespace)
    values = namespace['_contact_parameters'](str(PARAMS))
    assert values == _file_params()['contact_wrench'] and 'client_lanes' in values
    worker = ContactWrenchNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()])
    try:   # every value is one the node takes (a bad one raises here)
        assert worker.get_parameter('client_lanes').value == values['client_lanes']
    finally:
        worker.destroy_node()
