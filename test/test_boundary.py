"""The house rule, read from every file's syntax tree (imports inside functions count too).

Wings by who uses them:

* product: ground (``types``, ``errors``, ``rotations``, ``shapes``, ``paths``, ``dds``),
  ``surface``, ``pokes``, ``response``, ``contact``, ``effects``, ``model``, ``drivers``,
  ``deformation``, ``replica`` and the product ``nodes``; they never import ``sim``,
  ``bringup``, ``diagnose`` or ``lab``;
* everything but ``nodes``, ``bringup`` and ``msg_adapters`` is ROS-free (no rclpy, no message
  or interface packages); ``sim`` in particular never imports ROS;
* a function-local import of a project module needs a stated reason (a ``#`` comment on its
  line); everything else goes at the top of the module;
* no import cycle between wings.

A second test imports every ROS-free module with ROS made unimportable, so that a hidden
dynamic import is caught too.
"""

import ast
from pathlib import Path
import subprocess
import sys
import textwrap

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'pointforce_ros'
PRODUCT = {'types', 'errors', 'rotations', 'shapes', 'paths', 'dds', 'surface', 'pokes',
           'response', 'contact', 'effects', 'model', 'drivers', 'deformation', 'replica', 'nodes'}
RESEARCH = {'sim', 'bringup', 'diagnose', 'lab'}
ROS_ALLOWED = {'nodes', 'bringup'}
ROS_TOPS = ('rclpy', 'rosidl_runtime_py', 'pointforce_interfaces', 'ament_index_python')


def wing_of(module: str) -> str:
    """Wing of a dotted module name inside the package (``pointforce_ros.sim.fem`` -> ``sim``)."""
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else ''


def is_ros(module: str) -> bool:
    """Whether an imported module is ROS (rclpy, a message or interface package)."""
    top = module.split('.')[0]
    return top in ROS_TOPS or top.endswith(('_msgs', '_srvs')) or top == 'msg_adapters'


def imports_of(path: Path):
    """Yield ``(imported module, line, inside a function, line text)`` for one file."""
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source)
    local = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            local.update(id(n) for n in ast.walk(node)
                         if isinstance(n, (ast.Import, ast.ImportFrom)))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or '']
            if node.module == 'pointforce_ros':  # from pointforce_ros import sim
                names = [f'pointforce_ros.{a.name}' for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            yield name, node.lineno, id(node) in local, lines[node.lineno - 1]


def module_name(path: Path) -> str:
    """Dotted name of a file under the package."""
    rel = path.relative_to(ROOT).with_suffix('')
    parts = list(rel.parts)
    if parts[-1] == '__init__':
        parts = parts[:-1]
    return '.'.join(parts)


def violations(root: Path = PACKAGE):
    """Every broken rule under ``root`` as ``file:line: what``."""
    found = []
    edges = {}
    for path in sorted(root.rglob('*.py')):
        module = module_name(path)
        wing = wing_of(module)
        for name, line, local, text in imports_of(path):
            where = f'{path.relative_to(ROOT)}:{line}'
            if name.startswith('pointforce_ros.'):
                target = wing_of(name)
                if target != wing:
                    edges.setdefault(wing, set()).add(target)
                if wing in PRODUCT and target in RESEARCH:
                    found.append(f'{where}: product wing {wing!r} imports {name}')
                if local and '#' not in text:
                    found.append(f'{where}: function-local import of {name} with no reason')
            elif is_ros(name) and wing not in ROS_ALLOWED:
                found.append(f'{where}: ROS module {name} imported below nodes/ ({wing!r})')
    found.extend(f'import cycle between wings: {" -> ".join(c)}' for c in _cycles(edges))
    return found


def _cycles(edges):
    cycles = []
    for start in sorted(edges):
        stack = [(start, [start])]
        while stack:
            node, path = stack.pop()
            for nxt in sorted(edges.get(node, ())):
                if nxt == start and len(path) > 1:
                    cycles.append(path + [start])
                elif nxt not in path and nxt > start:
                    stack.append((nxt, path + [nxt]))
    return cycles


def test_the_package_keeps_the_house_rule():
    assert violations() == []


@pytest.mark.parametrize('wing, line, broken', [
    ('model', "    from pointforce_ros.sim.objects import load_object  # needed\n",
     "product wing 'model' imports pointforce_ros.sim.objects"),
    ('contact', '    from pointforce_ros.types import Surface\n',
     'function-local import of pointforce_ros.types with no reason'),
    ('sim', '    import rclpy  # a clock\n', "ROS module rclpy imported below nodes/ ('sim')"),
    ('response', '    from pointforce_ros import lab  # figures\n',
     "product wing 'response' imports pointforce_ros.lab"),
])
def test_the_rule_catches_a_forbidden_import_inside_a_function(tmp_path, monkeypatch,
                                                               wing, line, broken):
    # a copy of the package with one import added inside a function
    fake_root = tmp_path / 'repo'
    target = fake_root / 'pointforce_ros' / wing
    target.mkdir(parents=True)
    (target / 'bad.py').write_text('def f():\n' + line + '    return 1\n')
    monkeypatch.setattr(sys.modules[__name__], 'ROOT', fake_root)
    found = violations(fake_root / 'pointforce_ros')
    assert len(found) == 1 and broken in found[0], found


def test_the_rule_catches_a_cycle_between_wings(tmp_path, monkeypatch):
    fake_root = tmp_path / 'repo'
    for wing, other in (('sim', 'lab'), ('lab', 'sim')):
        (fake_root / 'pointforce_ros' / wing).mkdir(parents=True)
        (fake_root / 'pointforce_ros' / wing / 'a.py').write_text(
            f'from pointforce_ros.{other}.a import x\n')
    monkeypatch.setattr(sys.modules[__name__], 'ROOT', fake_root)
    assert violations(fake_root / 'pointforce_ros') == [
        'import cycle between wings: lab -> sim -> lab']


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
        if info.name.split('.')[1] in ('nodes', 'bringup'):
            continue
        importlib.import_module(info.name)
        checked.append(info.name)
    assert not any(m.split('.')[0] == 'rclpy' for m in sys.modules), 'rclpy got imported'
    print(len(checked))
''')


def test_ros_free_wings_import_with_ros_blocked():
    result = subprocess.run([sys.executable, '-c', SCRIPT], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert int(result.stdout.strip().splitlines()[-1]) >= 60


def test_the_blocker_itself_catches_a_ros_import():
    script = SCRIPT.replace('import pointforce_ros\n', 'import pointforce_ros\nimport rclpy\n', 1)
    result = subprocess.run([sys.executable, '-c', script], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode != 0 and 'core imported ROS module rclpy' in result.stderr
