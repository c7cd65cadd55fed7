"""Where the package's shipped files are: object and scenario YAML, the live FEM tables.

The same lookup serves a source checkout (``make``'s editable install), a pip install into a
prefix and a colcon install: files are installed to ``<prefix>/share/pointforce_ros`` (see
``setup.py``'s ``data_files``) and found from there, never through ``test/``.
"""

import os
from pathlib import Path
import sys
from typing import List

PACKAGE = 'pointforce_ros'

_HERE = Path(__file__).resolve().parent


def share_dirs() -> List[Path]:
    """Candidate share folders, most specific first (only those that exist).

    1. the source checkout this module was imported from (``package.xml`` beside the package);
    2. ``ament_index_python``'s share directory of the package, when a ROS environment is
       sourced (``AMENT_PREFIX_PATH``);
    3. the install prefix this module lives under (``<prefix>/lib/pythonX.Y/site-packages``);
    4. ``sys.prefix``.
    """
    found = []
    checkout = _HERE.parent
    if (checkout / 'package.xml').is_file():
        found.append(checkout)
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        # ament_index_python's lookup, without importing it: the marker file of a package
        if prefix and (Path(prefix) / 'share' / 'ament_index' / 'resource_index' / 'packages'
                       / PACKAGE).is_file():
            found.append(Path(prefix) / 'share' / PACKAGE)
    if len(_HERE.parents) > 4 and _HERE.parents[1].name == 'lib':
        found.append(_HERE.parents[3] / 'share' / PACKAGE)
    elif len(_HERE.parents) > 4 and _HERE.parents[2].name == 'lib':
        found.append(_HERE.parents[3] / 'share' / PACKAGE)
    found.append(Path(sys.prefix) / 'share' / PACKAGE)
    unique = []
    for path in found:
        if path.is_dir() and path not in unique:
            unique.append(path)
    return unique


def share_path(*parts: str) -> Path:
    """Return the path of a shipped file or folder (``config/objects``, ``data/fem``, ...).

    Returns the first candidate of :func:`share_dirs` that has it; if none has it, the path
    under the first candidate (so an error message names a sensible place), or under the
    checkout when no share folder exists at all.
    """
    dirs = share_dirs()
    for base in dirs:
        if (base.joinpath(*parts)).exists():
            return base.joinpath(*parts)
    return (dirs[0] if dirs else _HERE.parent).joinpath(*parts)
