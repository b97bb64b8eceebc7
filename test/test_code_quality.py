"""The code base's own checks: ruff (format and lint, ament's rules), mypy, imports and layers."""

from __future__ import annotations

import ast
from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / 'memo_ros'
LAYERS = ('core', 'ros', 'nodes', 'tools')  # each may import only from itself and those before it
CORE_ORDER = {  # a core sub-package may import only the sub-packages listed for it
    'geometry': set(),
    'vision': {'geometry'},
    'multiview': {'geometry'},
    'walking': {'geometry'},
    'formats': {'geometry'},
    'simulation': {'geometry', 'walking'},
    'evaluation': {'geometry', 'vision', 'formats'},
    'latency': set(),
}
ROS_PACKAGES = ('rclpy', 'rosidl_runtime_py', 'rosbags')
MESSAGE_SUFFIX = '_msgs'
# fields only a message has: a core function reading one takes a message object
MESSAGE_FIELDS = {'header', 'is_bigendian', 'get_fields_and_field_types', 'point_step', 'row_step'}


def _tool(*args: str) -> subprocess.CompletedProcess:
    """Run a module of the venv's Python in the repository root, capturing its output."""
    return subprocess.run(
        [sys.executable, '-m', *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def _modules() -> dict[str, Path]:
    """Map every module of the package (dotted name) to its file."""
    names = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        parts = path.relative_to(ROOT).with_suffix('').parts
        if parts[-1] == '__init__':
            parts = parts[:-1]
        names['.'.join(parts)] = path
    return names


def _imports(path: Path) -> set[str]:
    """Return every module a file imports, at the top or inside functions (absolute names)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f'{node.module}.{alias.name}' for alias in node.names)
    return found


def _package_graph() -> dict[str, set[str]]:
    """Return the import graph between the package's own modules."""
    modules = _modules()
    return {
        name: {m for m in _imports(path) if m in modules and m != name}
        for name, path in modules.items()
    }


def test_ruff_format_leaves_every_file_as_it_is():
    done = _tool('ruff', 'format', '--check', '--no-cache', '.')
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]


def test_ruff_check_finds_nothing():
    done = _tool('ruff', 'check', '--no-cache', '--output-format', 'concise', '.')
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]


def test_mypy_finds_nothing_in_the_core(tmp_path):
    # mypy.ini names the files (memo_ros/core); a fresh cache keeps a clean clone's run honest
    done = _tool('mypy', '--config-file', 'mypy.ini', '--cache-dir', str(tmp_path / 'mypy'))
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]


def test_every_module_imports_in_a_fresh_interpreter():
    names = [n for n in _modules() if not n.endswith('__main__')]
    script = (
        'import importlib, sys\n'
        'bad = []\n'
        f'for name in {names!r}:\n'
        '    try:\n'
        '        importlib.import_module(name)\n'
        '    except Exception as exc:  # noqa: BLE001 - report every failure\n'
        '        bad.append(f"{name}: {exc!r}")\n'
        'print("\\n".join(bad))\n'
        'sys.exit(1 if bad else 0)\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', script], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]


def test_the_import_graph_has_no_cycle():
    graph = _package_graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f'import cycles: {cycles}'


def _layer(module: str) -> str | None:
    parts = module.split('.')
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else None


def test_layers_import_only_downwards():
    wrong = []
    for name, targets in _package_graph().items():
        layer = _layer(name)
        if layer is None:
            continue
        allowed = set(LAYERS[: LAYERS.index(layer) + 1])
        wrong += [f'{name} -> {t}' for t in targets if _layer(t) not in allowed | {None}]
    assert not wrong, '\n'.join(wrong)


def test_core_sub_packages_import_only_what_they_build_on():
    wrong = []
    for name, targets in _package_graph().items():
        parts = name.split('.')
        if len(parts) < 3 or parts[1] != 'core':
            continue
        own = parts[2]
        if own not in CORE_ORDER:
            wrong.append(f'{name}: not in a known core sub-package')
            continue
        for t in targets:
            other = t.split('.')[2] if t.startswith('memo_ros.core.') else None
            if other and other != own and other not in CORE_ORDER[own]:
                wrong.append(f'{name} -> {t}')
    assert not wrong, '\n'.join(wrong)


def test_the_core_imports_no_ros_and_takes_no_message():
    wrong = []
    for name, path in _modules().items():
        if not name.startswith('memo_ros.core'):
            continue
        for imported in _imports(path):
            top = imported.split('.')[0]
            if top in ROS_PACKAGES or top.endswith(MESSAGE_SUFFIX):
                wrong.append(f'{name} imports {imported}')
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for arg in node.args.args + node.args.kwonlyargs:
                    if arg.arg == 'msg' or arg.arg.endswith(('_msg', '_message', '_msgs')):
                        wrong.append(f'{name}.{node.name} takes {arg.arg!r}')
                reads = {a.attr for a in ast.walk(node) if isinstance(a, ast.Attribute)}
                if reads & MESSAGE_FIELDS:
                    wrong.append(f'{name}.{node.name} reads {sorted(reads & MESSAGE_FIELDS)}')
    assert not wrong, '\n'.join(wrong)


@pytest.mark.parametrize('layer', ['core', 'ros', 'nodes', 'tools'])
def test_each_layer_is_a_package(layer):
    assert (PACKAGE / layer / '__init__.py').is_file()
