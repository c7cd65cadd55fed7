"""Write requirements.lock from the current venv: installable pins only.

The ROS 2 wheels bundle extra distributions (``rclpy``, ``action_msgs``, ``rosidl_adapter`` ...)
whose names are not on the index; each of them is the payload of a ``ros-<name>`` wheel that is
pinned itself, so they are left out. Our own packages are left out too.
"""

import subprocess
import sys


def main() -> int:
    """Print the lock to stdout."""
    freeze = subprocess.run([sys.executable, '-m', 'pip', 'freeze', '--exclude-editable'],
                            capture_output=True, text=True, check=True).stdout.splitlines()
    pins = {}
    for line in freeze:
        if '==' in line:
            name, version = line.split('==', 1)
            pins[name.lower()] = (name, version)
    keep = []
    for key, (name, version) in sorted(pins.items()):
        canonical = key.replace('_', '-')
        if key.startswith('pointforce'):
            continue
        if not key.startswith('ros-') and f'ros-{canonical}' in pins:
            continue  # bundled inside the ros-<name> wheel
        keep.append(f'{name}=={version}')
    print('\n'.join(keep))
    return 0


if __name__ == '__main__':
    sys.exit(main())
