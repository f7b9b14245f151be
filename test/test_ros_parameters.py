"""Node parameters the ROS way, driven only through the real ``ros2`` command line (ros2cli):
``ros2 param set`` of bad values is refused with the reason it prints, live parameters take
effect (their value in effect shows in the node's /diagnostics status: waited for with
``ros2 topic echo --filter``), the services that switch a live parameter keep it coherent,
``ros2 param dump`` loads back with ``--params-file``, and the shipped parameter files
(config/params/<machine>.yaml) are what the code generates, load in any namespace and give
every node of the bringup graph its values.

Real node processes over real DDS, in this session's ROS domain, discovery on localhost
(ros_fixtures.ros_env); a few processes per class, stopped at the end of the class whatever
happened. Every wait is on a condition (a printed line, a status showing a value); the
timeouts only bound a wait that would otherwise hang."""
import importlib.util
import itertools
import shutil
import signal
import subprocess
import sys
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import yaml

from machine_ctrl import parameters
from machine_ctrl.app.processes import Supervisor
from machine_ctrl.shared_memory import empty_ports, remove_stale_ports
from machine_ctrl.model.config import load_machine
from ros_fixtures import without_fastdds_log

ROS2 = Path(sys.executable).parent / 'ros2'
PARAMS_DIR = Path(__file__).resolve().parents[1] / 'config' / 'params'
CLI = pytest.mark.skipif(not ROS2.is_file() or importlib.util.find_spec('ros2cli') is None,
                         reason=f'the ros2 command line is not installed ({ROS2} or the ros2cli package missing)')
WAIT = 60            # s: bounds a wait for a condition (never reached when things work)
READY = 120          # s: a node process up (imports, Pinocchio) on a loaded machine


# What a `ros2` call that sent its request and never got the answer is doing when it is stopped:
# waiting in rclpy's spin_until_future_complete (param set/get/dump, service call).
ANSWER_WAIT = 'in spin_until_future_complete'
RETRIES = itertools.count(1)      # the lost answers retried (numbered warnings)


def ros2(env, *args, timeout=WAIT + 30) -> subprocess.CompletedProcess:
    """`ros2 ARGS`, as a user runs it. One that has not ended after `timeout` s gets SIGABRT,
    so that Python's faulthandler (PYTHONFAULTHANDLER) prints where it hangs, and the test
    fails with that and the empty Fast DDS port files of the moment (machine_ctrl.app.
    shared_memory): `ros2 param set` waits for its answer without a limit. Empty port files left
    by killed processes are removed first, as a Supervisor does before it starts a node: a
    participant that opens one waits forever (machine_ctrl.shared_memory; the suite kills
    many nodes).

    One kind of hang is retried once, as its user would: the call sent its request and waits
    for an answer that never comes (its stack is in spin_until_future_complete). Loaded runs
    saw it twice in ~10 runs (run115: `ros2 service call`; run119: `ros2 param set` of a value
    rclpy itself refuses by its range, with 15 such calls 4 at a time), with nothing in the
    node's log (which logs a response rclpy could not send: node_common.log_runtime_warnings):
    the answer is lost between the node's response writer and the new CLI process's reader
    (rmw_fastrtps drops a response whose reader it has not matched: ros2/rmw_fastrtps#704, or
    silently when it does not know the client). Every call retried here is idempotent (a set
    of the same value, a get, a dump, a SetBool); the retry is a warning (pytest's summary
    lists it), and a second hang fails."""
    for attempt in (1, 2):
        remove_stale_ports()
        process = subprocess.Popen([str(ROS2), *args], env={**env, 'PYTHONFAULTHANDLER': '1'}, text=True,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            out, err = process.communicate(timeout=timeout)
            return subprocess.CompletedProcess(process.args, process.returncode, out, err)
        except subprocess.TimeoutExpired:
            process.send_signal(signal.SIGABRT)
            try:
                out, err = process.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                out, err = process.communicate()
        stacks = (out + err)[-4000:]
        if attempt == 1 and ANSWER_WAIT in stacks:
            # a warning, not a print: pytest's summary shows it for a test that then passes, so a
            # loaded run's log counts these losses (a print of a passing test is not shown)
            # numbered: Python reports one warning per text and line, and each loss must show
            warnings.warn(f'ros2 {" ".join(args)}: no answer within {timeout} s (lost: see ros2()); asked once more '
                          f'(retry {next(RETRIES)} of this session)')
            continue
        empty = [path.name for path, _ in empty_ports()]
        raise AssertionError(f'ros2 {" ".join(args)}: not ended within {timeout} s (attempt {attempt}); empty port '
                             f'files {empty}; its output and stacks:\n{stacks}')


def param_set(env, node, name, value) -> str:
    """What `ros2 param set` prints (its one line, stdout or stderr)."""
    result = ros2(env, 'param', 'set', '--no-daemon', '--timeout', str(WAIT), node, name, value)
    return (result.stdout + result.stderr).strip()


def param_get(env, node, name) -> str:
    result = ros2(env, 'param', 'get', '--no-daemon', '--timeout', str(WAIT), node, name)
    return (result.stdout + result.stderr).strip()


def param_dump(env, node) -> str:
    result = ros2(env, 'param', 'dump', '--no-daemon', '--timeout', str(WAIT), node)
    assert result.returncode == 0, result.stderr
    return result.stdout


def in_parallel(calls):
    """Run independent CLI calls side by side (each waits on discovery, not on the CPU)."""
    with ThreadPoolExecutor(max_workers=4) as pool:
        return list(pool.map(lambda call: call[0](*call[1:]), calls))


def wait_status(env, node_name: str, values: dict | None = None, **more) -> dict:
    """Wait (ros2 topic echo --once --filter) for a /diagnostics status of `node_name`
    whose values include `values` (as the node prints them); returns that status's values,
    its message under 'message' and its level under 'level'."""
    values = {**(values or {}), **more}
    wanted = ' and '.join(f'kv.get({key!r}) == {str(value)!r}' for key, value in values.items())
    expr = (f'any(s.name == {node_name!r} and (lambda kv: {wanted})({{v.key: v.value for v in s.values}}) '
            'for s in m.status)')
    result = ros2(env, 'topic', 'echo', '--no-daemon', '--once', '--timeout', str(WAIT), '--filter', expr,
                  '/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')
    assert result.returncode == 0 and result.stdout.strip(), \
        f'no status of {node_name} with {values} within {WAIT} s: {result.stderr[-2000:]}'
    message = next(doc for doc in yaml.safe_load_all(without_fastdds_log(result.stdout)) if doc)
    (status,) = [s for s in message['status'] if s['name'] == node_name]
    return {'message': status['message'], 'level': status['level'],
            **{kv['key']: kv['value'] for kv in status['values']}}


@pytest.fixture(scope='class')
def supervisor(ros_env, tmp_path_factory):
    with Supervisor(ros_env, log_dir=tmp_path_factory.mktemp('logs'), stop_timeout=3.0) as supervisor:
        yield supervisor


def start(supervisor, specs, directory):
    supervisor.start_nodes(specs, directory)
    for spec in specs:
        supervisor.wait_for_line(spec.name, 'ready', READY)


# --- trt_5axis stepping: hw_sim (paced, 100 steps/s), servo, reference (hold), contour_error ----------

@pytest.fixture(scope='class')
def trt_graph(trt, supervisor, tmp_path_factory):
    from machine_ctrl.ros.graph import default_graph
    specs = default_graph(trt, contour='hold', hw_sim={'mode': 'paced', 'real_time_factor': 0.1},
                          contour_error=True)
    assert sorted(s.name for s in specs) == ['contour_error', 'hw_sim', 'reference', 'servo_coarse']
    start(supervisor, specs, tmp_path_factory.mktemp('params'))
    return supervisor


@CLI
class TestTrtGraph:
    def test_bad_values_are_refused_with_their_reason_and_change_nothing(self, ros_env, trt_graph):
        servo, contour = '/servo_coarse', '/contour_error'
        before = in_parallel([(param_dump, ros_env, servo), (param_dump, ros_env, contour)])
        reason = parameters.SIM_TIME_REASON
        cases = [   # node, parameter, value, what ros2 param set prints
            (servo, 'gains.x.gain', '-1.0', 'Setting parameter failed: Parameter gains.x.gain out of range '
             'Min: 0.0, Max: 1.7976931348623157e+308, value: -1.0'),                             # negative
            (servo, 'gains.x.gain', '.nan', 'Setting parameter failed: Parameter gains.x.gain out of range '
             'Min: 0.0, Max: 1.7976931348623157e+308, value: nan'),                              # NaN
            (servo, 'gains.a.bandwidth', '0.0', 'Setting parameter failed: gains.a.bandwidth: must be > 0 1/s, '
             'got 0.0'),                                                                         # zero
            (servo, 'gains.x.gain', '5000.0', 'Setting parameter failed: gains.x: gain: T (K_s / m_e + lambda) = '
             '3.29 must be < 1 (the sampled loop would oscillate or diverge'),                   # unstable
            (servo, 'gains.x.gain', '700', "Setting parameter failed: Wrong parameter type, expected "
             "'Type.DOUBLE' got 'Type.INTEGER'"),                                                # wrong type
            (servo, 'feedforward', 'maybe', "Setting parameter failed: Wrong parameter type, expected "
             "'Type.BOOL' got 'Type.STRING'"),
            (servo, 'contour_control', '1', "Setting parameter failed: Wrong parameter type, expected "
             "'Type.BOOL' got 'Type.INTEGER'"),
            (servo, 'use_sim_time', 'false', f'Setting parameter failed: use_sim_time: {reason}, got false'),
            (servo, 'machine', 'micromill_9axis', 'Setting parameter failed: Trying to set a read-only '
             'parameter: machine.'),                                                             # another machine
            (servo, 'axes', "['x', 'q']", 'Setting parameter failed: Trying to set a read-only parameter: axes.'),
            (servo, 'input_timeout', '-1.0', 'Setting parameter failed: Trying to set a read-only parameter: '
             'input_timeout.'),
            (contour, 'estimator', 'fancy', "Setting parameter failed: estimator: must be basic, shifted or "
             "compensated, got 'fancy'"),                                                        # unknown choice
            (contour, 'use_sim_time', 'false', f'Setting parameter failed: use_sim_time: {reason}, got false'),
            ('/hw_sim', 'mode', 'turbo', 'Setting parameter failed: Trying to set a read-only parameter: mode.'),
            ('/reference', 'lookahead_steps', '0', 'Setting parameter failed: Trying to set a read-only parameter: '
             'lookahead_steps.'),
        ]
        printed = in_parallel([(param_set, ros_env, node, name, value) for node, name, value, _ in cases])
        for (node, name, value, line), out in zip(cases, printed):
            assert out.startswith(line), (node, name, value, out)
        after = in_parallel([(param_dump, ros_env, servo), (param_dump, ros_env, contour)])
        assert [yaml.safe_load(text) for text in after] == [yaml.safe_load(text) for text in before]
        trt_graph.check()

    def test_the_contour_node_reports_start_up_as_a_state_not_a_warning(self, ros_env, trt_graph):
        """hw_sim (paced) steps from the start, the reference may come later: those states are
        start-up, not 'steps without reference' for the rest of the run."""
        values = wait_status(ros_env, 'contour_error', skipped_steps=0, gaps=0)
        assert int(values['estimated_step']) > 0 and values['message'] == 'ok', values
        assert values['level'] == '\x00', values                      # OK, not WARN

    def test_live_changes_take_effect_at_the_next_step(self, ros_env, trt_graph):
        servo = '/servo_coarse'
        assert wait_status(ros_env, 'servo_coarse', feedforward=True)['gains.x.gain'] == '700.0'
        assert wait_status(ros_env, 'servo_coarse', contour_control=False)['contour_control_status'] == 'off'
        printed = in_parallel([(param_set, ros_env, servo, 'gains.x.gain', '600.0'),
                               (param_set, ros_env, servo, 'feedforward', 'false'),
                               (param_set, ros_env, servo, 'contour_control', 'true'),
                               (param_set, ros_env, '/contour_error', 'estimator', 'basic')])
        assert printed == ['Set parameter successful'] * 4
        # the law runs with the new gain; feed-forward is off from a step at rest (the hold
        # streams rest rows, and hw_sim steps); the contour control runs (servo_coarse holds
        # every axis of trt_5axis's); the estimator formula is the basic one
        values = wait_status(ros_env, 'servo_coarse', **{'gains.x.gain': 600.0, 'feedforward': False,
                                                         'contour_control': True})
        assert values['feedforward_requested'] == '' and values['gains.y.gain'] == '500.0', values
        assert values['contour_control_status'] in ('active', 'fading'), values
        assert int(values['answered_step']) > 0
        wait_status(ros_env, 'contour_error', estimator='basic')
        assert in_parallel([(param_get, ros_env, servo, 'gains.x.gain'),
                            (param_get, ros_env, servo, 'feedforward')]) == ['Double value is: 600.0',
                                                                            'Boolean value is: False']
        trt_graph.check()


def test_contour_control_is_refused_with_the_reason_where_the_node_cannot_run_it(micromill, fts_lathe):
    """The check servo_node declares for `contour_control` (a set, at start or live, is refused
    with this text): the node must hold every coupled axis of a machine that has a
    contour_control section."""
    from machine_ctrl.ros.servo_node import contour_check
    check = contour_check(micromill)
    assert check.test({'axes': ['x_f', 'y_f', 'z_f', 'a_f'], 'contour_control': True}) is None
    assert check.test({'axes': ['x_c', 'y_c', 'z_c'], 'contour_control': False}) is None       # off: anywhere
    assert check.test({'axes': ['x_c', 'y_c', 'z_c'], 'contour_control': True}) == \
        'the node must hold every coupled axis (x_f y_f z_f); it has x_c y_c z_c'
    assert contour_check(fts_lathe).test({'axes': ['w'], 'contour_control': True}) == \
        'fts_lathe has no contour_control section in its machine config'


# --- micromill: the switches that are also services -------------------------------------------------

@pytest.fixture(scope='class')
def switches(micromill, supervisor, tmp_path_factory):
    from machine_ctrl.ros.graph import NodeSpec
    model = str(micromill.simulation.error_map_path(micromill.yaml_path))
    specs = [NodeSpec('dual_stage', 'machine_ctrl.ros.dual_stage_node', 'DualStageNode', {'machine': 'micromill_9axis'}),
             NodeSpec('compensation', 'machine_ctrl.ros.compensation_node', 'CompensationNode',
                      {'machine': 'micromill_9axis', 'model': model})]
    start(supervisor, specs, tmp_path_factory.mktemp('params'))
    return supervisor


def service_call(env, service, kind, request) -> str:
    result = ros2(env, 'service', 'call', service, kind, request)
    assert result.returncode == 0, result.stderr
    return result.stdout


@CLI
class TestSwitches:
    def test_parameter_and_service_are_one_switch(self, ros_env, switches):
        assert in_parallel([(param_set, ros_env, '/dual_stage', 'dual_stage', 'false'),
                            (param_set, ros_env, '/compensation', 'enabled', 'false')]) == ['Set parameter successful'] * 2
        in_parallel([(wait_status, ros_env, 'dual_stage', {'dual_stage': False}),
                     (wait_status, ros_env, 'compensation', {'enabled': False})])
        answers = in_parallel([(service_call, ros_env, '/dual_stage/enable', 'std_srvs/srv/SetBool', '{data: true}'),
                               (service_call, ros_env, '/compensation/enable', 'std_srvs/srv/SetBool', '{data: true}')])
        assert all('success=True' in answer for answer in answers), answers
        assert in_parallel([(param_get, ros_env, '/dual_stage', 'dual_stage'),
                            (param_get, ros_env, '/compensation', 'enabled')]) == ['Boolean value is: True'] * 2
        in_parallel([(wait_status, ros_env, 'dual_stage', {'dual_stage': True}),
                     (wait_status, ros_env, 'compensation', {'enabled': True})])
        printed = in_parallel([(param_set, ros_env, '/dual_stage', 'dual_stage', '1'),
                               (param_set, ros_env, '/compensation', 'model', 'other.yaml')])
        assert printed == ["Setting parameter failed: Wrong parameter type, expected 'Type.BOOL' got 'Type.INTEGER'",
                           'Setting parameter failed: Trying to set a read-only parameter: model.']
        switches.check()


# --- parameter files: the shipped ones, and ros2 param dump loading back ------------------------------

def test_shipped_parameter_files_are_what_the_code_generates():
    from machine_ctrl.ros.node_parameters import SHIPPED_MACHINES, params_file_text
    for name in SHIPPED_MACHINES:
        assert (PARAMS_DIR / f'{name}.yaml').read_text() == params_file_text(load_machine(name)), \
            f'config/params/{name}.yaml is stale: python -m machine_ctrl.ros.node_parameters --write config/params'
    assert sorted(p.name for p in PARAMS_DIR.iterdir()) == sorted(f'{n}.yaml' for n in SHIPPED_MACHINES)


@pytest.mark.parametrize('machine_name', ['micromill_9axis', 'trt_5axis'])
def test_every_node_of_the_graph_takes_its_section_in_any_namespace(machine_name, ros_env, tmp_path):
    """Each node of the bringup graph, created under a namespace with the shipped file as
    --params-file, has exactly the file's values (the nested gains as gains.<axis>.<gain>)."""
    import rclpy
    from rclpy.context import Context

    from rclpy.parameter import Parameter

    from test_parameters import node_class
    machine = load_machine(machine_name)
    path = PARAMS_DIR / f'{machine_name}.yaml'
    document = yaml.safe_load(path.read_text())
    executables = {'hw_sim': 'hw_sim_node', 'servo_coarse': 'servo_node', 'servo_fine': 'servo_node',
                   'dual_stage': 'dual_stage_node', 'trajectory': 'trajectory_node', 'contour_error': 'contour_error_node',
                   'compensation': 'compensation_node', 'recorder': 'recorder_node'}
    needed = {'recorder': {'output': str(tmp_path / 'bag')}}       # required, left to the command line
    if machine.dual_stage:
        needed['compensation'] = {'model': str(machine.simulation.error_map_path(machine.yaml_path))}
    assert set(document) == {f'/**/{name}' for name in executables if name in needed or name != 'compensation'
                             } - ({'/**/servo_fine', '/**/dual_stage'} if not machine.dual_stage else set())
    context = Context()
    rclpy.init(args=['test', '--ros-args', '--params-file', str(path)], context=context,
               domain_id=int(ros_env['ROS_DOMAIN_ID']))
    try:
        for key, section in document.items():
            name = key.rsplit('/', 1)[-1]
            overrides = [Parameter(k, value=v) for k, v in needed.get(name, {}).items()]
            node = node_class(executables[name])(name=name, namespace='/cell7', context=context,
                                                 parameter_overrides=overrides)
            try:
                for param, value in _flat(section['ros__parameters']).items():
                    assert node.get_parameter(param).value == value, (name, param)
            finally:
                node.destroy_node()
    finally:
        context.try_shutdown()


def _flat(tree, prefix=''):
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


@CLI
def test_a_dump_starts_a_fresh_node_with_the_same_values(ros_env, tmp_path):
    """The shipped file in a namespace, live changes, `ros2 param dump` to a file; a fresh
    node started from that file with --params-file dumps the same values."""
    argv = [sys.executable, '-m', 'machine_ctrl.ros.servo_node', '--ros-args', '-r', '__node:=servo_coarse',
            '-r', '__ns:=/cell1']
    node = '/cell1/servo_coarse'
    with Supervisor(ros_env, log_dir=tmp_path / 'logs', stop_timeout=3.0) as supervisor:
        supervisor.start('first', argv + ['--params-file', str(PARAMS_DIR / 'micromill_9axis.yaml')])
        supervisor.wait_for_line('first', 'ready', READY)
        assert in_parallel([(param_get, ros_env, node, 'gains.y_c.gain'), (param_get, ros_env, node, 'axes')]) == \
            ['Double value is: 250.0', "String values are: ['x_c', 'y_c', 'z_c']"]
        assert in_parallel([(param_set, ros_env, node, 'gains.x_c.gain', '60.0'),
                            (param_set, ros_env, node, 'gains.z_c.adaptation', '0.0'),
                            (param_set, ros_env, node, 'feedforward', 'false')]) == ['Set parameter successful'] * 3
        dump = tmp_path / 'servo_coarse.yaml'
        dump.write_text(param_dump(ros_env, node))
        supervisor.stop('first')
        supervisor.start('fresh', argv + ['--params-file', str(dump)])
        supervisor.wait_for_line('fresh', 'ready', READY)
        again = yaml.safe_load(param_dump(ros_env, node))
        first = yaml.safe_load(dump.read_text())
        assert again == first
        values = first[node]['ros__parameters']
        assert (values['gains']['x_c']['gain'], values['gains']['z_c']['adaptation'], values['feedforward']) == \
            (60.0, 0.0, False)
        supervisor.check()


@CLI
def test_bad_values_at_start_end_the_node_with_one_line(ros_env, tmp_path):
    """The same table refuses start-up values (`--ros-args -p`): exit 2, one FATAL line."""
    base = [sys.executable, '-m', 'machine_ctrl.ros.servo_node', '--ros-args', '-p', 'machine:=trt_5axis']
    machines = Path(__file__).resolve().parents[1] / 'config' / 'machines'
    shutil.copy(machines / 'trt_5axis.urdf', tmp_path)        # a period the step clock cannot stamp
    (tmp_path / 'odd.yaml').write_text((machines / 'trt_5axis.yaml').read_text().replace(
        'control_period: 1.0e-3 ', 'control_period: 1.0000005e-3 ', 1))
    cases = [(['-p', 'axes:=[x, q]'], "parameter axes: must name controlled axes of trt_5axis (x, y, z, a, c), "
              "each once; unknown 'q'"),
             (['-p', 'use_sim_time:=false'], f'parameter use_sim_time: {parameters.SIM_TIME_REASON}, got false'),
             (['-p', 'gains.c.adaptation:=-3.0'], 'parameter gains.c.adaptation: must be >= 0 V/m (V/rad), got -3.0'),
             (['-p', f'machine:={tmp_path / "odd.yaml"}'],
              'control_period: control period 0.0010000005 s is not a whole number of nanoseconds '
              '(a graph stamps every step in integer ns)')]

    def run(extra):
        return subprocess.run(base + extra, env=ros_env, capture_output=True, text=True, timeout=READY)
    for (extra, line), result in zip(cases, in_parallel([(run, extra) for extra, _ in cases])):
        fatal = [text for text in (result.stdout + result.stderr).splitlines() if 'FATAL' in text]
        assert result.returncode == 2 and len(fatal) == 1 and fatal[0].endswith(line), (extra, result.stderr)
