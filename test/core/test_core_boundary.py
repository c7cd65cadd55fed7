"""The pure core never imports ROS: import every core module with rclpy made unimportable."""

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import importlib, pkgutil, sys

    class BlockRos:
        """Refuse rclpy, message packages and rosidl runtime."""

        def find_spec(self, name, path=None, target=None):
            top = name.split('.')[0]
            if top in ('rclpy', 'rosidl_runtime_py', 'pointforce_interfaces') or \\
                    top.endswith('_msgs') or top.endswith('_srvs'):
                raise ImportError(f'core imported ROS module {name}')
            return None

    sys.meta_path.insert(0, BlockRos())
    import pointforce_ros
    checked = []
    for info in pkgutil.walk_packages(pointforce_ros.__path__, 'pointforce_ros.'):
        if info.name.startswith('pointforce_ros.nodes') or info.name == 'pointforce_ros.cli':
            continue
        importlib.import_module(info.name)
        checked.append(info.name)
    assert not any(m.split('.')[0] == 'rclpy' for m in sys.modules), 'rclpy got imported'
    print(len(checked))
''')


def test_core_imports_without_ros():
    result = subprocess.run([sys.executable, '-c', SCRIPT], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert int(result.stdout.strip().splitlines()[-1]) >= 8


def test_the_blocker_itself_catches_a_ros_import():
    script = SCRIPT.replace('import pointforce_ros\n', 'import pointforce_ros\nimport rclpy\n', 1)
    result = subprocess.run([sys.executable, '-c', script], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode != 0 and 'core imported ROS module rclpy' in result.stderr
