"""The machine-ctrl console script, run as a user runs it."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from test_kinematics_micromill import thesis_chain
from test_kinematics_trt import eq4, eq7

EXE = str(Path(sys.executable).parent / 'machine-ctrl')


def run(*args, stdin=''):
    return subprocess.run([EXE, *args], input=stdin, capture_output=True, text=True, timeout=60)


def test_info_json_is_one_object_with_the_machine():
    result = run('info', '--json')
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert info['name'] == 'micromill_9axis'
    assert [a['name'] for a in info['axes']] == ['x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f']
    axes = {a['name']: a for a in info['axes']}
    assert axes['x_c']['stroke'] == [-0.05, 0.05] and axes['x_c']['drive'] == 'linear_motor'
    assert axes['c_f']['stroke'] is None and axes['c_f']['unit'] == 'rad'
    assert set(axes['y_f']) >= {'velocity', 'acceleration', 'jerk', 'sensor_resolution'}
    _, tip, axis = thesis_chain(np.zeros(9))
    np.testing.assert_allclose(info['home']['tool_tip'], tip, atol=1e-15)
    np.testing.assert_allclose(info['home']['tool_axis'], axis, atol=1e-15)


def test_info_text_lists_every_axis_in_order():
    result = run('info', 'trt_5axis')
    assert result.returncode == 0, result.stderr
    rows = [line.split()[0] for line in result.stdout.splitlines()]
    start = rows.index('axis') + 1
    assert rows[start:start + 5] == ['x', 'y', 'z', 'a', 'c']
    assert 'unlimited' in result.stdout and 'home tool tip' in result.stdout


def test_fk_prints_one_line_per_configuration_and_reports_bad_lines():
    good = np.array([[0.0] * 9,
                     [0.01, -0.02, 0.03, 5e-5, -5e-5, 2e-5, 0.004, -0.003, 0.7],
                     [-0.04, 0.04, -0.01, -9e-5, 9e-5, -9e-5, -0.008, 0.008, -12.0]])
    lines = [' '.join(map(repr, good[0].tolist())),
             '# a comment', '',
             '1 2 3',                                   # wrong count
             ' '.join(map(repr, good[1].tolist())),
             '0 0 0 0 0 0 0 0 x',                       # not a number
             '0 0 0 0 0 0 0 nan 0',                     # NaN
             '0 0 0 0 0 0 inf 0 0',                     # inf
             '\t'.join(map(repr, good[2].tolist()))]
    result = run('fk', stdin='\n'.join(lines) + '\n')
    assert result.returncode == 1
    out = np.array([[float(v) for v in line.split()] for line in result.stdout.splitlines()])
    assert out.shape == (3, 6)
    for q, row in zip(good, out):
        _, tip, axis = thesis_chain(q)
        np.testing.assert_allclose(row, np.concatenate((tip, axis)), rtol=0, atol=1e-12)
    errors = result.stderr.splitlines()
    assert [e.split(':')[0] for e in errors] == ['line 4', 'line 6', 'line 7', 'line 8']
    assert 'expected 9 values, got 3' in errors[0]
    assert 'not finite' in errors[2]


def test_fk_on_the_trt_machine_exit_0_when_all_lines_are_good():
    q = [0.01, -0.02, 0.05, 0.3, -2.0]
    result = run('fk', 'trt_5axis', stdin=' '.join(map(str, q)) + '\n')
    assert result.returncode == 0, result.stderr
    row = np.array(result.stdout.split(), float)
    np.testing.assert_allclose(row, np.concatenate((eq7(q), eq4(q))), rtol=0, atol=1e-12)


DOCUMENTED_COMMANDS = ['info', 'fk', 'experiment', 'plan', 'record', 'replay', 'analyze',
                       'bringup', 'send', 'move', 'freeform', 'demo', 'view', 'fit-errors', 'identify']
EXPERIMENTS = ['circle', 'square', 'frf', 'contour', 'midrange', 'piezo-milling', 'deflection', 'feed-force',
               'fts-budget', 'fts-freeform', 'fts-h2', 'fts-accel', 'fts-flexure', 'fts-identify', 'geometric']


def _subcommands(parser):
    import argparse
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(actions) == 1
    return actions[0].choices


def test_every_command_group_registers_its_subcommands():
    import argparse
    from machine_ctrl.app import cli
    names = []
    for group in cli.COMMAND_GROUPS:              # each group on a root parser of its own
        root = argparse.ArgumentParser(prog='machine-ctrl')
        group.register(root.add_subparsers(dest='command', required=True))
        registered = _subcommands(root)
        assert registered, group.__name__
        for name, parser in registered.items():
            assert name not in names, f'{name} registered twice'
            names.append(name)
            if name != 'experiment':
                assert callable(parser.get_default('run')), f'{name} has no handler'
    assert names == DOCUMENTED_COMMANDS
    commands = _subcommands(cli.build_parser())
    assert list(commands) == DOCUMENTED_COMMANDS
    experiments = _subcommands(commands['experiment'])
    assert list(experiments) == EXPERIMENTS
    assert all(callable(p.get_default('run')) for p in experiments.values())


def test_importing_the_cli_imports_neither_ros_nor_the_cores():
    code = ('import json, sys\n'
            'from machine_ctrl.app import cli\n'
            'cli.build_parser()\n'
            'print(json.dumps(sorted(sys.modules)))\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    loaded = {name.split('.')[0] for name in json.loads(result.stdout)}
    assert not loaded & {'rclpy', 'rosbag2_py', 'numpy', 'pinocchio', 'trajectory', 'compensation', 'hw_sim'}


def test_nothing_in_app_imports_the_cli_and_experiments_import_no_ros():
    import ast
    root = Path(__file__).resolve().parents[1] / 'machine_ctrl'

    def imports(path):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                yield from (a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module:
                yield node.module
                yield from (f'{node.module}.{a.name}' for a in node.names)

    for path in (root / 'app').rglob('*.py'):
        if path.parent.name != 'cli':                # the CLI package itself
            assert not [m for m in imports(path) if m == 'machine_ctrl.app.cli' or m.startswith('machine_ctrl.app.cli.')], path
    for path in (root / 'experiments').rglob('*.py'):
        bad = [m for m in imports(path) if m.split('.')[0] == 'rclpy' or m.startswith('machine_ctrl.ros')]
        assert not bad, f'{path}: {bad}'


def test_usage_errors_exit_2_with_one_error_line():
    for args in (['bogus'], ['experiment', 'bogus'], ['analyze', 'a', 'b', 'c'], ['fit-errors', 'x.csv', '--bogus']):
        result = run(*args)
        assert result.returncode == 2 and result.stdout == ''
        errors = [line for line in result.stderr.splitlines() if line.startswith('machine-ctrl')]
        assert len(errors) == 1 and ': error: ' in errors[0], result.stderr
    result = run('fit-errors', 'x.csv', '--bogus')
    assert 'machine-ctrl fit-errors: error: unrecognized arguments: --bogus' in result.stderr
    result = run('experiment', 'frf', '--record', 'nowhere')
    assert result.returncode == 2 and result.stderr == 'machine-ctrl: experiment: --record is for circle and square\n'


def test_bringup_send_and_move_take_the_graph_namespace():
    from machine_ctrl.app import cli
    parser = cli.build_parser()
    for command in (['bringup'], ['send', 'circle_xy'], ['move', 'x_c=0.001']):
        assert parser.parse_args(command).namespace == ''
        assert parser.parse_args(command + ['--namespace', 'mill1']).namespace == '/mill1'
    result = run('move', 'x_c=0.001', '--namespace', '1bad')
    assert result.returncode == 2 and 'is not a ROS namespace' in result.stderr


def test_a_seed_table_experiment_that_fails_exits_1_with_its_reason(monkeypatch, capsys):
    """An experiment that ran and reports a failure is not a usage error (exit 2): exit 1 and
    its reason on stderr, its table printed as usual."""
    import argparse
    import types

    from machine_ctrl.app.cli.experiment import cmd_seed_table
    failing = types.ModuleType('machine_ctrl.experiments.failing_for_test')
    failing.reproduce = lambda: {'status': 'failed', 'reason': 'the loop went unstable'}
    failing.format_table = lambda result: 'seed | ours | ratio'
    monkeypatch.setitem(sys.modules, failing.__name__, failing)
    status = cmd_seed_table(argparse.Namespace(module='failing_for_test', entry='reproduce', json=False,
                                               name='failing', plots=None))
    out, err = capsys.readouterr()
    assert status == 1
    assert out == 'seed | ours | ratio\n'
    assert err == 'machine-ctrl: experiment failing: the loop went unstable\n'
