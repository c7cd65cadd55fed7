"""The contact service's core loads only what it uses (issue 16: back within 2 s after a kill).

Every restart of ``contact_wrench`` pays for its imports: ``scipy.signal`` (which loads
``scipy.stats``) and ``scipy.optimize`` were half of its start-up until the effect corrections
and the shape-constant identification were kept off the serving path. A fresh interpreter
imports the serving core and lists what came with it.
"""

import json
import subprocess
import sys

NOT_ON_THE_SERVICE_PATH = (
    'scipy.signal', 'scipy.stats', 'scipy.optimize', 'scipy.interpolate', 'sklearn', 'open3d',
    'pointforce_ros.effects.correct', 'pointforce_ros.effects.relaxation',
    'pointforce_ros.contact.identify', 'pointforce_ros.pokes.curves', 'rclpy')


def test_the_serving_core_imports_no_fitting_or_signal_processing():
    code = ('import json, sys\n'
            'import pointforce_ros.model.serving\n'
            f'print(json.dumps([m for m in {NOT_ON_THE_SERVICE_PATH!r} if m in sys.modules]))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
