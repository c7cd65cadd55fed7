"""``pointforce health``: the cell's nodes' ``/diagnostics`` reports, as a table.

There is no rqt_robot_monitor or ros2cli in this environment; this listens to ``/diagnostics``
(``diagnostic_msgs/DiagnosticArray``, each node's report once a second:
:func:`pointforce_ros.nodes.common.publish_health`) for ``wait`` seconds in the ROS graph of
this environment (``ROS_DOMAIN_ID``), keeps each status name's newest report, and prints one
line per name: level, name, message (``--json``: one object with the values too). When
``wait`` ends with nothing heard, or with a ``/diagnostics`` publisher discovered that has not
reported yet, it listens up to :data:`LATE_GRACE` seconds more: a new DDS participant here
sometimes discovers the nodes only 1.7 s after it starts, or later (seen in session 41 beside
a participant that had just left), and a 2.5 s wait then heard nothing. The exit code says
the worst level heard: 0 every report OK, 1 a WARN, 2 an ERROR or a stale report, 3 no
report at all (no node of the cell running in this domain).
"""

import json
import time
from typing import Dict

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.errors import InvalidInput

LEVELS = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}
EXIT_NONE = 3
"""Exit code when no report was heard."""

LATE_GRACE = 3.0
"""Seconds past ``wait`` spent waiting for a discovered publisher's first report."""


def collect(launcher, wait: float) -> Dict[str, dict]:
    """Listen to ``/diagnostics`` for ``wait`` seconds; return each status name's newest one.

    Each entry: ``level`` (0-3), ``message``, ``hardware_id``, ``values`` (dict), ``stamp``
    (seconds, the report's header).
    """
    heard: Dict[str, dict] = {}

    def on_report(msg):
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        for status in msg.status:
            heard[status.name] = dict(level=int.from_bytes(status.level, 'little'),
                                      message=status.message, hardware_id=status.hardware_id,
                                      values={v.key: v.value for v in status.values},
                                      stamp=stamp)
    node = launcher.add(Node('pointforce_health', context=launcher.context))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_report, 50)
    start = time.monotonic()
    while True:
        time.sleep(0.05)
        elapsed = time.monotonic() - start
        if elapsed < wait:
            continue
        publishers = {info.node_name for info in
                      node.get_publishers_info_by_topic('/diagnostics')}
        reported = {name.split(':', 1)[0] for name in list(heard)}
        if (heard and publishers <= reported) or elapsed >= wait + LATE_GRACE:
            return dict(heard)


def run_health(wait: float = 3.0, json_out: bool = False) -> int:
    """CLI body: print the newest report of every node heard; return the exit code."""
    if not wait > 0 or wait > 600:
        raise InvalidInput(f'--wait must be in (0, 600] s, got {wait}')
    with InProcessLauncher(threads=1) as launcher:
        heard = collect(launcher, wait)
    worst = max((r['level'] for r in heard.values()), default=None)
    if json_out:
        print(json.dumps({'reports': heard, 'worst': None if worst is None
                          else LEVELS.get(worst, str(worst))}, sort_keys=True))
    elif not heard:
        print(f'[health] no /diagnostics report in {wait:g} s: is a node of the cell running '
              'in this ROS domain (ROS_DOMAIN_ID)?')
    else:
        width = max(len(name) for name in heard)
        for name in sorted(heard):
            report = heard[name]
            print(f'{LEVELS.get(report["level"], str(report["level"])):5s} '
                  f'{name:{width}s}  {report["message"]}')
    if worst is None:
        return EXIT_NONE
    return 0 if worst == 0 else (1 if worst == 1 else 2)
