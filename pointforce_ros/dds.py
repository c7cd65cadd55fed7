"""The package's Fast DDS profiles: faster rediscovery of restarted nodes.

``config/fastdds.xml`` is the nodes' profile (participants re-announce every 0.2 s, a silent
one is dropped after 5 s); ``config/fastdds_planner.xml`` is for the processes that call the
contact service (the same, plus a 100 ms health check of shared-memory ports, so a client is
not held up by a killed service's ports). Each is set before the first ``rclpy.init`` of a
process (Fast DDS reads the profile file once, when its participant factory starts). A profile
the user already names in the environment wins.
"""

import os
from typing import Optional

from pointforce_ros.paths import share_path

PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')
"""The environment variables Fast DDS (2.x, Jazzy) reads a default profile file from."""

PROFILES = {'node': 'fastdds.xml', 'planner': 'fastdds_planner.xml'}
"""Kind of process -> the package's profile file under ``config/``."""


def package_dds_profile(kind: str = 'node') -> Optional[str]:
    """Return the path of the package's profile for ``kind`` (``None`` if not installed)."""
    path = share_path('config', PROFILES[kind])
    return str(path) if path.is_file() else None


def use_package_dds_profile(environ=None, kind: str = 'node') -> Optional[str]:
    """Name the package's ``kind`` profile in ``environ`` (``os.environ``) unless one is named.

    A profile of the package's own of another kind is replaced (a node started by a planner
    process gets the nodes' profile); the user's own profile is kept.

    Returns:
        The profile file now in effect (the user's or the package's); ``None`` when the package
        file is not installed and none was named.

    """
    env = os.environ if environ is None else environ
    ours = {package_dds_profile(k) for k in PROFILES} - {None}
    named = [env[name] for name in PROFILE_VARIABLES if env.get(name)]
    if named and not set(named) <= ours:
        return named[0]
    path = package_dds_profile(kind)
    if path is None:
        return named[0] if named else None
    for name in PROFILE_VARIABLES:
        env.pop(name, None)
    env[PROFILE_VARIABLES[0]] = path
    return path
