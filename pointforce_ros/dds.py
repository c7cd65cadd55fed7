"""The package's Fast DDS profile (``config/fastdds.xml``): faster rediscovery of restarted nodes.

Set before the first ``rclpy.init`` of a process (Fast DDS reads the profile file once, when its
participant factory starts). A profile the user already names in the environment wins.
"""

import os
from typing import Optional

from pointforce_ros.paths import share_path

PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')
"""The environment variables Fast DDS (2.x, Jazzy) reads a default profile file from."""


def use_package_dds_profile(environ=None) -> Optional[str]:
    """Name the package's Fast DDS profile in ``environ`` (``os.environ``) unless one is named.

    Returns:
        The profile file now in effect (the user's or the package's); ``None`` when the package
        file is not installed and none was named.

    """
    env = os.environ if environ is None else environ
    for name in PROFILE_VARIABLES:
        if env.get(name):
            return env[name]
    path = share_path('config', 'fastdds.xml')
    if not path.is_file():
        return None
    env[PROFILE_VARIABLES[0]] = str(path)
    return str(path)
