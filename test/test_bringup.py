"""`machine-ctrl bringup` as a user runs it (its own process, the session's ROS domain),
driven by `machine-ctrl move` / `send` as another program would; Ctrl-C stops everything:
no process left, the bag closed, valid and analysable. Plus: a node executable takes its
parameters from `--params-file`."""
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from machine_ctrl.recording import analysis

EXE = str(Path(sys.executable).with_name('machine-ctrl'))


def graph_processes(domain_id: str) -> list[int]:
    """pids of our node processes (python -m <node module>) in this ROS domain."""
    found = []
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / 'cmdline').read_bytes().split(b'\0')
            environ = (entry / 'environ').read_bytes().split(b'\0')
        except OSError:
            continue
        if b'-m' in cmdline and f'ROS_DOMAIN_ID={domain_id}'.encode() in environ:
            found.append(int(entry.name))
    return found


def client(ros_env, *args, timeout=300):
    return subprocess.run([EXE, *args], env=ros_env, capture_output=True, text=True, timeout=timeout)


def test_bringup_runs_commands_and_stops_cleanly_on_ctrl_c(ros_supervisor, ros_env, tmp_path, micromill):
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
    ros_supervisor.wait_for_line('bringup', '/trajectory/feed_override', timeout=10)   # the API table
    assert len(graph_processes(ros_env['ROS_DOMAIN_ID'])) == 7       # 6 nodes + the recorder

    done = client(ros_env, 'move', 'x_c=0.001', 'y_c=-0.0005')
    assert done.returncode == 0, done.stderr
    assert 'done: joint goal' in done.stdout
    refused = client(ros_env, 'move', 'x_f=0.001')
    assert refused.returncode == 1
    assert 'refused: joint goal' in refused.stderr and 'outside its stroke' in refused.stderr
    csv = tmp_path / 'far.csv'
    csv.write_text('px,py,pz,oi,oj,ok\n' + ''.join(f'{0.3 + i * 1e-3},0,0,0,0,1\n' for i in range(10)))
    refused = client(ros_env, 'send', str(csv))
    assert refused.returncode == 1 and 'planning failed' in refused.stderr, refused.stderr
    ros_supervisor.wait_for_line('bringup', 'state running: joint goal', timeout=10)   # state changes shown

    child.signal_group(signal.SIGINT)              # what Ctrl-C in the terminal does
    assert ros_supervisor.wait('bringup', timeout=120) == 0
    output = '\n'.join(child.tail(200))
    assert 'recorded ' in output and '/joint_states (sensor_msgs/msg/JointState)' in output
    assert graph_processes(ros_env['ROS_DOMAIN_ID']) == []           # no orphans
    run = analysis.load(bag)                                        # closed, valid, names its machine
    moved = run.reference[-1] - run.reference[0]
    np.testing.assert_allclose(moved[:2], [0.001, -0.0005], atol=1e-9)


def test_move_finds_the_graph_of_its_namespace(ros_supervisor, ros_env, micromill):
    """A graph in namespace /mill1 (all nodes in one process): `move --namespace mill1`
    waits for its readiness, follows its goal and succeeds; the root namespace has no graph."""
    ros_supervisor.start('graph', [sys.executable, '-m', 'machine_ctrl.ros.graph', '--machine', str(micromill.yaml_path),
                                   '--contour', 'none', '--namespace', 'mill1'])
    ros_supervisor.wait_for_line('graph', 'graph ready at step', timeout=180)    # hw_sim's log
    done = client(ros_env, 'move', 'x_c=0.001', '--namespace', 'mill1')
    assert done.returncode == 0, done.stderr
    assert 'succeeded' in done.stdout and 'done: joint goal (1 points)' in done.stdout
    elsewhere = client(ros_env, 'move', 'x_c=0.001', '--timeout', '3', timeout=60)
    assert elsewhere.returncode == 2 and 'the graph is not ready after 3 s' in elsewhere.stderr


def test_send_and_move_refuse_bad_arguments_with_one_line(ros_env):
    for args, text in ((['move', 'x_c'], "expected AXIS=VALUE"), (['move', 'x_c=abc'], 'is not a number'),
                       (['move', 'x_c=nan'], 'not finite'), (['send', 'no_such.csv'], 'no_such.csv'),
                       (['send', 'circle_xy', '--timeout', '0'], '--timeout must be > 0')):
        result = client(ros_env, *args, timeout=60)
        assert result.returncode == 2, (args, result.stderr)
        assert result.stderr.count('\n') == 1 and text in result.stderr, (args, result.stderr)


def test_no_graph_is_reported_not_waited_for_forever(ros_env):
    result = client(ros_env, 'move', 'x_c=0.001', '--timeout', '3', timeout=60)
    assert result.returncode == 2
    assert result.stderr == 'machine-ctrl: move: the graph is not ready after 3 s: is it up? machine-ctrl bringup\n'


def test_a_node_takes_its_parameters_from_a_params_file(ros_supervisor, ros_node, tmp_path, micromill):
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor
    params = tmp_path / 'params.yaml'
    params.write_text('contour_error:\n  ros__parameters:\n    estimator: basic\n')
    exe = str(Path(sys.executable).with_name('contour_error_node'))
    ros_supervisor.start('contour_error', [exe, '--ros-args', '--params-file', str(params),
                                           '-p', f'machine:={micromill.yaml_path}'])
    node = ros_node('params_probe')
    service = node.create_client(GetParameters, '/contour_error/get_parameters')
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        assert service.wait_for_service(timeout_sec=60)
        future = service.call_async(GetParameters.Request(names=['estimator', 'machine']))
        executor.spin_until_future_complete(future, timeout_sec=30)
        values = future.result().values
        assert values[0].string_value == 'basic'                   # from the file (default: compensated)
        assert values[1].string_value == str(micromill.yaml_path)  # from -p
    finally:
        executor.shutdown()


def test_paced_bringup_steps_on_the_wall_clock_moves_records_and_reports_its_timing(
        ros_supervisor, ros_env, ros_node, tmp_path, trt):
    """`bringup trt_5axis --paced --real-time-factor 0.2 --single-process --record`: hw_sim
    steps paced (its diagnostics say so), a move succeeds, the diagnostics carry the paced
    timing (the step latency of steps since ready, its percentiles in order), and the
    recording (which hw_sim does not wait for when paced) holds the move. The schedule itself
    is tested on fake time (test_hw_sim_session.py)."""
    import time

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    # the probe joins before the graph, so that it is discovered with it (run128: one made
    # after the move, on a heavily loaded machine, heard none of hw_sim's 1 Hz diagnostics
    # in 60 s, which the graph's recorder holds); its queue keeps the newest 10 meanwhile
    node = ros_node('paced_probe')
    heard = []                                     # hw_sim's values
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda msg: heard.extend(
        {kv.key: kv.value for kv in s.values} for s in msg.status if s.name == 'hw_sim'), 10)
    bag = tmp_path / 'bag'
    child = ros_supervisor.start('bringup', [EXE, 'bringup', 'trt_5axis', '--paced', '--real-time-factor', '0.2',
                                             '--single-process', '--record', str(bag)])
    ros_supervisor.wait_for_line('bringup', 'paced by the wall clock at 0.2x real time', timeout=60)
    ros_supervisor.wait_for_line('bringup', 'all nodes ready', timeout=180)
    done = client(ros_env, 'move', 'x=0.01', '--machine', 'trt_5axis')
    assert done.returncode == 0, done.stderr

    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    def timed():        # hw_sim's reports with the latency of some steps (those after ready)
        return [values for values in heard if int(values.get('step_latency_count', '0')) > 0]
    deadline = time.monotonic() + 60
    while not timed() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
    executor.shutdown()
    assert timed(), f'no diagnostics from hw_sim with step latencies ({len(heard)} without)'
    assert all(values['mode'] == 'paced' and values['fault'] == '' for values in heard)
    last = timed()[-1]
    p50, p99, top = (float(last[f'step_latency_{k}']) for k in ('p50', 'p99', 'max'))
    assert 0.0 < p50 <= p99 <= top

    child.signal_group(signal.SIGINT)
    assert ros_supervisor.wait('bringup', timeout=120) == 0
    run = analysis.load(bag)
    assert run.reference[-1][0] == pytest.approx(0.01, abs=1e-9)       # the move's goal, recorded
    assert run.session == {'mode': 'paced', 'real_time_factor': '0.2'}    # the bag says how its graph ran


def test_the_recorder_of_a_bringup_keeps_how_its_graph_runs(trt, tmp_path):
    """bringup's (and the launch file's) recorder gets the session facts: hw_sim's mode, its
    real-time factor when paced, the servos' belief files; a bad fact is refused."""
    from machine_ctrl.app.bringup import graph_specs, recorder_spec
    from machine_ctrl.ros.graph import NodeSpec
    belief = tmp_path / 'x.yaml'
    belief.write_text('axes:\n  x:\n    drive:\n      mass: 300.0\n')

    def session(**options):
        specs = graph_specs(trt, record=True, **options)
        return recorder_spec(trt, str(tmp_path / 'bag'), specs).parameters['session']
    assert session() == ['mode=lockstep']
    assert session(paced=0.5, belief=[str(belief)]) == ['mode=paced', 'real_time_factor=0.5', f'belief_1={belief}']
    with pytest.raises(ValueError, match="parameter session: 'bad' is not KEY=VALUE"):
        NodeSpec('recorder', 'machine_ctrl.ros.recorder_node', 'RecorderNode', {'output': 'x', 'session': ['bad']})
