"""The layering of README "Architecture", checked from the source (AST), so it stays true:

* no import cycle between modules, and none between folders;
* imports run one way: a folder imports only folders of its own layer or below;
* the ROS-free layers import no ROS package, directly or through another module of ours;
  every module of the ROS layer is a ROS module (the roof, a command tree with ROS and
  ROS-free commands, is the one layer that holds both);
* no folder holds more than 30 % of the lines;
* every topic and service name is written in one module, machine_ctrl/contract.py, and so
  is the nanoseconds-per-second arithmetic of the step clock.

Imports inside functions count like any other: a lazy import is still a dependency.
"""
from __future__ import annotations

import ast
import collections
import re
from pathlib import Path

import pytest

from machine_ctrl import contract

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ('machine_ctrl', 'trajectory', 'compensation', 'hw_sim')

# folder -> layer; a folder may import its own layer and those below (README "Architecture")
LAYERS = {
    'machine_ctrl/model': 0,          # ground: machine config, URDF, kinematics
    'machine_ctrl': 1,                # the contract (and the package's own __init__)
    'machine_ctrl/control': 2,        # ROS-free cores
    'machine_ctrl/contour': 2,
    'machine_ctrl/recording': 2,
    'machine_ctrl/identification': 2,
    'machine_ctrl/view': 2,           # the Foxglove view of a session (live or a bag)
    'trajectory': 2,
    'compensation': 2,
    'hw_sim': 2,
    'machine_ctrl/experiments': 3,    # ROS-free experiments composed of the cores, run offline
    'machine_ctrl/ros': 4,            # the ROS side: message conversion, thin nodes
    'machine_ctrl/app': 5,            # the roof: bringup, process supervision, client, demo
    'machine_ctrl/app/cli': 5,        # the machine-ctrl command tree
}
ROS_LAYER = 4
ROS_PACKAGES = re.compile(r'^(rclpy|rcl_interfaces|rosidl\w*|launch\w*|builtin_interfaces|rosgraph_msgs'
                          r'|\w+_msgs|\w+_srvs|\w+_interfaces|ros2\w*)$')
MAX_FOLDER_SHARE = 0.30


def _modules() -> dict[str, Path]:
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob('*.py')):
            name = '.'.join(path.relative_to(ROOT).with_suffix('').parts)
            modules[name.removesuffix('.__init__')] = path
    return modules


MODULES = _modules()
TREES = {name: ast.parse(path.read_text(), str(path)) for name, path in MODULES.items()}


def _folder(module: str) -> str:
    return str(MODULES[module].parent.relative_to(ROOT))


def _ours(target: str) -> str | None:
    """The module of ours that an imported name lives in (None: not ours)."""
    while target and target not in MODULES:
        target = target.rpartition('.')[0]
    return target or None


def _imports(module: str) -> tuple[set[str], set[str]]:
    """(modules of ours, top-level names of other packages) that `module` imports."""
    ours, others = set(), set()
    is_package = MODULES[module].name == '__init__.py'
    for node in ast.walk(TREES[module]):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                parts = module.split('.')
                parts = parts[:len(parts) - node.level + (1 if is_package else 0)]
                base = '.'.join(parts + ([node.module] if node.module else []))
            # `from pkg import mod` imports pkg.mod; `from mod import name` imports mod
            targets = [f'{base}.{alias.name}' if f'{base}.{alias.name}' in MODULES else base
                       for alias in node.names]
        else:
            continue
        for target in targets:
            mine = _ours(target)
            if mine is None:
                others.add(target.split('.')[0])
            elif mine != module:
                ours.add(mine)
    return ours, others


IMPORTS = {module: _imports(module) for module in MODULES}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_folder_has_a_layer():
    assert {_folder(m) for m in MODULES} == set(LAYERS)


def test_no_import_cycle_between_modules():
    graph = {module: ours for module, (ours, _) in IMPORTS.items()}
    assert not (cycles := _cycles(graph)), cycles


def test_no_import_cycle_between_folders():
    graph = collections.defaultdict(set)
    for module, (ours, _) in IMPORTS.items():
        graph[_folder(module)] |= {_folder(t) for t in ours if _folder(t) != _folder(module)}
    assert not (cycles := _cycles(graph)), cycles


def test_imports_run_one_way():
    upward = [f'{module} ({_folder(module)}, layer {LAYERS[_folder(module)]}) imports {target} '
              f'(layer {LAYERS[_folder(target)]})'
              for module, (ours, _) in IMPORTS.items() for target in sorted(ours)
              if LAYERS[_folder(target)] > LAYERS[_folder(module)]]
    assert not upward, '\n'.join(map(str, upward))


def _uses_ros() -> dict[str, bool]:
    """Whether each module imports a ROS package, directly or through modules of ours."""
    direct = {m: any(ROS_PACKAGES.match(p) for p in others) for m, (_, others) in IMPORTS.items()}
    uses = dict(direct)
    changed = True
    while changed:
        changed = False
        for module, (ours, _) in IMPORTS.items():
            if not uses[module] and any(uses[t] for t in ours):
                uses[module] = changed = True
    return uses


def test_ros_free_layers_import_no_ros():
    uses = _uses_ros()
    offenders = [m for m in MODULES if LAYERS[_folder(m)] < ROS_LAYER and uses[m]]
    assert not offenders, '\n'.join(map(str, offenders))


def test_the_ros_layer_holds_only_ros_modules():
    uses = _uses_ros()
    plain = [m for m in MODULES if LAYERS[_folder(m)] == ROS_LAYER and not uses[m]
             and MODULES[m].name != '__init__.py']
    assert not plain, '\n'.join(map(str, plain))


def test_no_folder_holds_more_than_30_percent_of_the_lines():
    lines = collections.Counter()
    for module, path in MODULES.items():
        lines[_folder(module)] += len(path.read_text().splitlines())
    total = sum(lines.values())
    assert {folder: round(n / total, 3) for folder, n in lines.items() if n > MAX_FOLDER_SHARE * total} == {}


def _docstrings(tree) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


# The contract's names are relative: searched for in their absolute form ('/joint_states'),
# and as written where they cannot be an English word ('trajectory/path', 'joint_states');
# 'clock', 'reference', 'ready' alone are words.
_RELATIVE = {item.name for item in contract.TOPICS + contract.SERVICES}
NAMES = sorted({'/' + name for name in _RELATIVE} | {name for name in _RELATIVE if '/' in name or '_' in name}
               | {contract.ROSOUT, contract.PARAMETER_EVENTS}, key=len, reverse=True)
# a ROS name of the contract inside a string: not preceded by a name character, a dot or a
# slash, not followed by a name character or a slash
NAME_IN_TEXT = re.compile('(?<![\\w./])(' + '|'.join(map(re.escape, NAMES)) + ')(?![\\w/])')


def test_topic_and_service_names_are_written_only_in_the_contract():
    found = []
    for module, tree in TREES.items():
        if module == 'machine_ctrl.contract':
            continue
        docstrings = _docstrings(tree)
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
                    and NAME_IN_TEXT.search(node.value)):
                found.append(f'{MODULES[module].relative_to(ROOT)}:{node.lineno}: {node.value!r}')
    assert not found, '\n'.join(map(str, found))


def test_nanoseconds_per_second_only_in_the_contract():
    found = [f'{MODULES[module].relative_to(ROOT)}:{node.lineno}'
             for module, tree in TREES.items() if module != 'machine_ctrl.contract'
             for node in ast.walk(tree)
             if isinstance(node, ast.Constant) and type(node.value) in (int, float) and node.value == 1e9]
    assert not found, '\n'.join(map(str, found))


@pytest.mark.parametrize('name', ['/trajectory/path', '/joint_states', '/dual_stage/enable', 'trajectory/path',
                                  'joint_states', '/clock'])
def test_the_name_check_finds_a_name_where_it_is_written(name):
    assert NAME_IN_TEXT.search(f'send it on {name} now')
    assert NAME_IN_TEXT.search(name + ' (never received)')
    assert not NAME_IN_TEXT.search(name + '/more')
    assert not NAME_IN_TEXT.search('x' + name)


def test_the_cycle_check_finds_a_cycle():
    assert _cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]
    assert _cycles({'a': {'b'}, 'b': set()}) == []


def test_the_ros_check_sees_ros_packages():
    assert all(ROS_PACKAGES.match(p) for p in ('rclpy', 'sensor_msgs', 'std_srvs', 'builtin_interfaces',
                                               'rcl_interfaces', 'launch_ros'))
    assert not any(ROS_PACKAGES.match(p) for p in ('numpy', 'pinocchio', 'mcap', 'yaml', 'ament_index_python'))
