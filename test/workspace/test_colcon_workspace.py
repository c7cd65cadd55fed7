"""The README's ROS-install path: a colcon workspace builds both packages and runs from install/.

The workspace is laid out exactly as the README says (this repository cloned as
``src/pointforce_ros``, colcon given it and its interface package as base paths). The built
``contact_wrench`` entry point then starts from ``install/`` with only ``install/local_setup.bash``
sourced, answers one contact query from a client that also runs from ``install/``, and exits
cleanly on SIGINT; the installed package finds its shipped objects, scenarios and FEM tables in
``install/pointforce_ros/share``.
"""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import textwrap

import pytest

from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model

pytestmark = [pytest.mark.slow, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
VENV = Path(sys.prefix)
PYTHON = VENV / 'bin' / 'python'  # the interpreter the ROS wheels live in (the underlay)
# the README's build command, run from the workspace root
BUILD = ['colcon', 'build', '--base-paths', 'src/pointforce_ros',
         'src/pointforce_ros/pointforce_interfaces', '--cmake-args', '-DBUILD_TESTING=OFF']

CLIENT = textwrap.dedent('''
    import sys
    import rclpy
    from geometry_msgs.msg import Vector3
    from pointforce_interfaces.srv import ContactWrench
    import pointforce_ros
    from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
    from pointforce_ros.nodes.direct_client import DirectClient
    from pointforce_ros.shapes import icosphere
    from pointforce_ros.types import Pose

    print('package', pointforce_ros.__file__, flush=True)
    rclpy.init()
    node = rclpy.create_node('install_planner')
    client = DirectClient(node, ContactWrench, '/contact_wrench/contact_wrench')
    # the installed server imports its numerics and loads the model before it is discovered:
    # 30 s was too short beside another test worker (session 36), so up to two minutes
    if not client.wait_for_service(timeout_sec=120.0):
        raise RuntimeError('/contact_wrench/contact_wrench did not appear within 120 s')
    pose = Pose(position=[0.5, 0.0, 0.057])
    request = ContactWrench.Request(
        mesh=mesh_to_msg(icosphere(0.02, 2)), pose=pose_to_msg(pose),
        approach=Vector3(x=0.0, y=0.0, z=-1.0), torque_centre=to_point(pose.position))
    # a planner's first query: Fast DDS may drop the response to a client the server has not
    # matched yet (session 32's CI run), so it may be asked again (DirectClient's attempts)
    response = client.call(request, timeout_sec=15.0, attempts=4)
    print('answer', response.success, response.wrench.force.z, response.model_version,
          repr(response.message), flush=True)
    client.destroy()
    node.destroy_node()
    rclpy.shutdown()
''')


def _tracked_files():
    out = subprocess.run(['git', 'ls-files', '-co', '--exclude-standard'], cwd=REPO,
                         capture_output=True, text=True, check=True).stdout
    return [line for line in out.splitlines() if (REPO / line).is_file()]


def _installed(ws: Path, command: str, **kwargs):
    """Run ``command`` in bash with only the workspace's ``install/local_setup.bash`` sourced."""
    dropped = ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH')
    env = {k: v for k, v in os.environ.items() if k not in dropped}
    env['AMENT_PREFIX_PATH'] = str(VENV)  # the ROS underlay: the wheels' prefix
    script = f'source {ws}/install/local_setup.bash && {command}'
    return subprocess.Popen(['bash', '-c', script], cwd=ws, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            **kwargs)


def _stop(server: subprocess.Popen) -> str:
    """Stop ``server`` with SIGINT (SIGKILL after 20 s) once; return all it printed."""
    if server.returncode is None:
        os.killpg(server.pid, signal.SIGINT)
        try:
            server.output, _ = server.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.output, _ = server.communicate()
    return server.output


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    if shutil.which('colcon') is None and not (VENV / 'bin' / 'colcon').exists():
        pytest.fail('colcon is not installed (colcon-common-extensions is in requirements)')
    ws = tmp_path_factory.mktemp('ws')
    src = ws / 'src' / 'pointforce_ros'
    for rel in _tracked_files():  # what `git clone` of this working tree would give
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / rel, src / rel)
    env = dict(os.environ, CMAKE_PREFIX_PATH=str(VENV), AMENT_PREFIX_PATH=str(VENV),
               PATH=f'{VENV / "bin"}{os.pathsep}{os.environ.get("PATH", "")}')
    env.pop('PYTHONPATH', None)
    build = subprocess.run(BUILD + [f'-DPython3_EXECUTABLE={VENV / "bin" / "python"}'],
                           cwd=ws, env=env, capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    assert '2 packages finished' in build.stdout, build.stdout[-2000:]
    return ws


def test_colcon_finds_both_packages_only_with_the_readme_layout(workspace):
    listed = subprocess.run([str(VENV / 'bin' / 'colcon'), 'list', '--names-only',
                             '--base-paths', 'src'], cwd=workspace, capture_output=True,
                            text=True, check=True).stdout.split()
    # the crawler stops at the outer package: that is why the README names both base paths
    assert listed == ['pointforce_ros']
    listed = subprocess.run([str(VENV / 'bin' / 'colcon'), 'list', '--names-only',
                             '--base-paths', 'src/pointforce_ros',
                             'src/pointforce_ros/pointforce_interfaces'], cwd=workspace,
                            capture_output=True, text=True, check=True).stdout.split()
    assert sorted(listed) == ['pointforce_interfaces', 'pointforce_ros']


def test_installed_contact_wrench_answers_a_query_and_exits(workspace, tmp_path):
    model = patch_contact_model(spacing=0.003)
    save_model(model, tmp_path / 'models')
    exe = workspace / 'install' / 'pointforce_ros' / 'lib' / 'pointforce_ros' / 'contact_wrench'
    assert exe.is_file()
    server = _installed(workspace, f'exec {exe} --ros-args -p model_dir:={tmp_path / "models"}')
    try:
        (tmp_path / 'client.py').write_text(CLIENT)
        client = _installed(workspace, f'exec {PYTHON} {tmp_path / "client.py"}')
        out, _ = client.communicate(timeout=300)
        if client.returncode != 0:
            pytest.fail(f'client:\n{out[-3000:]}\nserver:\n{_stop(server)[-3000:]}')
        package = next(line for line in out.splitlines() if line.startswith('package'))
        assert str(workspace / 'install' / 'pointforce_ros') in package, package
        answer = next(line for line in out.splitlines() if line.startswith('answer')).split()
        assert answer[1] == 'True', out[-2000:]
        assert float(answer[2]) > 0.1 and int(answer[3]) == model.version
    finally:
        server_out = _stop(server)
    assert server.returncode == 0, server_out[-3000:]


def test_installed_package_finds_its_shipped_files(workspace):
    share = workspace / 'install' / 'pointforce_ros' / 'share' / 'pointforce_ros'
    probe = _installed(workspace, f'exec {PYTHON} -c "'
                       'from pointforce_ros.sim.objects import list_objects, OBJECTS_DIR; '
                       'from pointforce_ros.sim.scenario import load_scenario; '
                       'from pointforce_ros.sim.fem.live import LiveContact, CACHE_DIR; '
                       'from pointforce_ros.sim.objects import load_object; '
                       'print(OBJECTS_DIR); print(CACHE_DIR); print(*list_objects()); '
                       "print(load_scenario('realistic').name); "
                       "print(LiveContact.load('lamb').spec.name)\"")
    out, _ = probe.communicate(timeout=300)
    assert probe.returncode == 0, out[-3000:]
    lines = out.strip().splitlines()
    assert lines[0] == str(share / 'config' / 'objects')
    assert lines[1] == str(share / 'data' / 'fem')
    assert {'lamb', 'plush', 'vest', 'dome', 'thin_layer'} <= set(lines[2].split())
    assert lines[3:] == ['realistic', 'lamb']
    exe = workspace / 'install' / 'pointforce_ros' / 'lib' / 'pointforce_ros' / 'pointforce'
    demo = _installed(workspace, f'exec {exe} demo --help')
    out, _ = demo.communicate(timeout=120)
    assert demo.returncode == 0 and '--object' in out, out[-2000:]
