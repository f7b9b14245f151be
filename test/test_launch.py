"""What a ROS user does, through the real `ros2` command line only: `ros2 launch machine_ctrl
bringup.launch.py` with a namespace and a recording, readiness and a joint goal seen with
`ros2 topic echo` / `ros2 topic pub`, Ctrl-C (SIGINT to the launch's process group, as a
terminal sends it) ending every node cleanly with the bag closed; and two machines in two
namespaces of one ROS domain, side by side.

Skipped, with the reason, where the ros2 command line / launch (../shared/ros2-tools) or the
package's ament layout (dev/_venv.sh, or `pip install .`) are not installed."""
import concurrent.futures
import importlib.util
import os
import re
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest
import yaml

from machine_ctrl.app.processes import default_stop_signals
from machine_ctrl.recording.bag import Bag
from machine_ctrl.ros.node_common import EXIT_LINE
from ros_fixtures import FASTDDS_LOG, ros2_daemons

BIN = Path(sys.executable).parent
ROS2 = BIN / 'ros2'
# generous limits for a busy 2-core machine; none of them is a measurement
READY_TIMEOUT = 180.0       # s
GOAL_TIMEOUT = 300.0        # s
EXIT_TIMEOUT = 60.0         # s
# The two-machine test's graphs (`params_file:=`): hw_sim's and the trajectory node's limits on
# their own stall and on missing answers, at the most that they take. This test is about
# namespaces, a recording and Ctrl-C, and is the suite's heaviest moment: three of its loaded
# runs (issue [6/8]) saw every process of both graphs not run for 4.3-5 s at once, the host
# stalling rather than the graph ("trajectory stalled", then "no answer to step k within 5 s").
# The fault tests (test_faults.py, test_a_killed_servo_... below) keep the defaults.
LOADED_HOST_PARAMS = {'/**/hw_sim': {'ros__parameters': {'command_timeout': 15.0}},
                      '/**/trajectory': {'ros__parameters': {'stall_limit': 6.0}}}


def _skip_reason() -> str | None:
    if not ROS2.exists():
        return f'the ros2 command line is not installed in {BIN} (../shared/ros2-tools/install)'
    if importlib.util.find_spec('launch_ros') is None:
        return 'launch_ros is not installed (../shared/ros2-tools/install)'
    from ament_index_python.packages import get_package_share_directory
    try:
        share = Path(get_package_share_directory('machine_ctrl'))
    except Exception as exc:  # noqa: BLE001 - PackageNotFoundError, or no AMENT_PREFIX_PATH
        return f'machine_ctrl is not in the ament index ({type(exc).__name__}: {exc}; dev/_venv.sh lays it out)'
    if not (share / 'launch/bringup.launch.py').exists():
        return f'{share}/launch/bringup.launch.py is not installed'
    return None


pytestmark = pytest.mark.skipif(_skip_reason() is not None, reason=str(_skip_reason()))


class Launch:
    """`ros2 launch machine_ctrl bringup.launch.py ARGS` in a session of its own (so a
    SIGINT to its process group is a terminal's Ctrl-C), output to a log file."""

    def __init__(self, env, log: Path, *args: str):
        self.log = log
        self.handle = open(log, 'wb')
        # with the signals at their defaults, as from a terminal, whatever this process ignores
        self.process = subprocess.Popen([str(ROS2), 'launch', 'machine_ctrl', 'bringup.launch.py', *args],
                                        env=env, stdout=self.handle, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, start_new_session=True,
                                        preexec_fn=default_stop_signals)

    def text(self) -> str:
        return self.log.read_text(errors='replace')

    def interrupt(self) -> tuple[int, float]:
        """Ctrl-C; (exit status, seconds until the launch ended)."""
        started = time.monotonic()
        os.killpg(self.process.pid, signal.SIGINT)
        try:
            status = self.process.wait(EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            self.kill()
            raise
        return status, time.monotonic() - started

    def kill(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()

    def close(self) -> None:
        self.kill()
        self.handle.close()


def ros2(env, *args: str, timeout: float = 60.0) -> str:
    result = subprocess.run([str(ROS2), *args], env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f'ros2 {" ".join(args)}: {result.stdout}{result.stderr}'
    return result.stdout


def end_reader(process: subprocess.Popen, grace: float = 10.0) -> None:
    """End a `ros2 topic echo` with SIGINT, so that it leaves the graph announced: a reliable
    reader killed without notice can hold the graph's writers for seconds (issue [6/8], the
    killed-recorder stall); SIGKILL only if it has not ended within `grace` s."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.communicate(timeout=grace)        # drains its output: a full pipe cannot hold it
        except subprocess.TimeoutExpired:
            process.kill()
    process.communicate()


def echo_until(env, topic: str, type_name: str, accept, launch: Launch, timeout: float, latched: bool = True):
    """Messages on `topic` (YAML documents of `ros2 topic echo`) until `accept(message)` is
    true: returns that message; fails with the launch output when none is accepted within
    `timeout` or the launch ended."""
    qos = ['--qos-durability', 'transient_local', '--qos-reliability', 'reliable'] if latched else []
    process = subprocess.Popen([str(ROS2), 'topic', 'echo', '--full-length', '--no-lost-messages', *qos, topic,
                                type_name], env=env,
                               stdout=subprocess.PIPE, text=True)
    timer = threading.Timer(timeout, process.kill)     # ends the read below when nothing comes
    timer.start()
    message = None
    try:
        document = []
        for line in process.stdout:
            if line.startswith(FASTDDS_LOG):            # Fast DDS logs on stdout too
                continue
            if line.strip() != '---':
                document.append(line)
                continue
            message = yaml.safe_load(''.join(document)) or {}
            document = []
            if accept(message):
                return message
            if launch.process.poll() is not None:
                break
    finally:
        timer.cancel()
        end_reader(process)
    pytest.fail(f'no accepted message on {topic} within {timeout:g} s; the last one read: {message}; '
                f'launch output:\n{launch.text()[-3000:]}')


def wait_ready(env, namespace: str, launch: Launch) -> None:
    echo_until(env, f'{namespace}/ready', 'std_msgs/msg/Bool', lambda m: m.get('data') is True, launch,
               READY_TIMEOUT)


def send_goal_and_follow(env, namespace: str, launch: Launch, goal: str, subscribers: int,
                         before: list | None = None) -> list[int]:
    """Publish a joint goal with `ros2 topic pub` once the goal status is being followed (the
    latched current list received), and return the statuses (action_msgs/GoalStatus codes)
    the newest goal goes through until it ends (succeeded 4, canceled 5, aborted 6).
    `subscribers`: every subscriber of the goal topic, or the goal may reach only some.
    `before`: if given, the latched list received before the goal was sent is appended to it
    (the goal status as it stood before this goal)."""
    seen: list[int] = []
    following = threading.Event()

    def ended(message) -> bool:
        if not following.is_set() and before is not None:
            before.append(message)
        following.set()
        statuses = message.get('status_list') or []
        if statuses and (not seen or seen[-1] != statuses[-1]['status']):
            seen.append(statuses[-1]['status'])
        return bool(seen) and seen[-1] in (4, 5, 6)

    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        done = pool.submit(echo_until, env, f'{namespace}/trajectory/goal_status', 'action_msgs/msg/GoalStatusArray',
                           ended, launch, GOAL_TIMEOUT)
        while not following.wait(1.0):
            if done.done():
                done.result()                    # fails with the launch output
        # --keep-alive: the publisher stays until the reliable delivery is through (its default
        # 0.1 s can end it first on a loaded machine: the goal never arrives)
        ros2(env, 'topic', 'pub', '--once', '-w', str(subscribers), '--keep-alive', '5',
             f'{namespace}/trajectory/joint_goal', 'trajectory_msgs/msg/JointTrajectory', goal)
        done.result()
    return seen


def side_by_side(*calls):
    """Independent waits of `ros2 topic echo` processes (call = (function, *args)) run at once:
    each waits on discovery and a message, not on the others; their results in order (the
    first failure is raised)."""
    with concurrent.futures.ThreadPoolExecutor(len(calls)) as pool:
        futures = [pool.submit(call[0], *call[1:]) for call in calls]
        return [future.result() for future in futures]


@pytest.fixture
def cli_env(ros_env):
    """The session's environment for the ros2 command line. `ros2 topic echo`, `topic list`,
    `param get` start a ros2 daemon (as for a user at a terminal); it is stopped at the end
    of the test, and found gone (ros_fixtures.ros2_daemons)."""
    env = {**ros_env, 'PATH': f'{BIN}{os.pathsep}{os.environ.get("PATH", "")}', 'PYTHONUNBUFFERED': '1'}
    yield env
    ros2(env, 'daemon', 'stop')            # returns once the daemon no longer answers; its process ends after
    deadline = time.monotonic() + EXIT_TIMEOUT
    while (left := ros2_daemons(int(env['ROS_DOMAIN_ID']))) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not left, f'ros2 daemon stop left the daemon running: pid {left}'


def lost_but_clean(text: str, died: list[str]) -> list[str]:
    """The lines of `died` where launch lost the exit status of a node that ended cleanly:
    asyncio's child watcher found the pid reaped already ('Unknown child process pid N, will
    report returncode 255': launch's own SIGINT, through Popen.send_signal, polls the child
    and reaps it when the terminal's Ctrl-C has ended it first) and reported 255, while the
    node's own last line says exit status 0 (README "For ROS users")."""
    lost = set(re.findall(r'Unknown child process pid (\d+), will report returncode 255', text))
    clean = []
    for line in died:
        m = re.search(r'\[(\S+)\]: process has died \[pid (\d+), exit code 255,', line)
        if m is None or m.group(2) not in lost:
            continue
        own = [x for x in text.splitlines() if x.startswith(f'[{m.group(1)}] ')]
        if own and own[-1] == f'[{m.group(1)}] {EXIT_LINE.format(status=0)}':
            clean.append(line)
    return clean


def test_a_lost_exit_status_is_excused_only_by_the_nodes_own_clean_last_line():
    """run158 (2026-12-07): launch reported servo_fine as died with 255, its own output said
    it shut down on SIGINT. Excused: that pid's status lost, and the node's last line exit 0;
    not a 255 of another pid, nor a node whose last line is not its clean end."""
    died = ("[ERROR] [servo_node-3]: process has died [pid 18426, exit code 255, cmd 'servo_node --ros-args']."
            "\n[ERROR] [servo_node-4]: process has died [pid 18427, exit code 255, cmd 'servo_node --ros-args'].")
    lines = died.splitlines()

    def log(last3, last4):
        return '\n'.join(['[WARNING] [asyncio]: Unknown child process pid 18426, will report returncode 255',
                          '[servo_node-3] [INFO] [1.0] [servo_fine]: SIGINT: shutting down', f'[servo_node-3] {last3}',
                          f'[servo_node-4] {last4}', died])
    clean = EXIT_LINE.format(status=0)
    assert lost_but_clean(log(clean, clean), lines) == lines[:1]          # 18427's status was not lost
    assert lost_but_clean(log(EXIT_LINE.format(status=1), clean), lines) == []
    assert lost_but_clean(log('Traceback (most recent call last):', clean), lines) == []


def assert_ended_cleanly(launch: Launch, status: int, nodes: int) -> None:
    """Exit status 0 and every node process launched (at least `nodes`) finished cleanly (or
    ended cleanly by its own last line where launch lost its status: :func:`lost_but_clean`)."""
    text = launch.text()
    assert status == 0, text[-3000:]
    assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, text[-3000:]
    started = [line for line in text.splitlines() if 'process started with pid' in line]
    finished = [line for line in text.splitlines() if 'process has finished cleanly' in line]
    died = [line for line in text.splitlines() if 'process has died' in line]
    excused = lost_but_clean(text, died)
    if excused:
        warnings.warn(f'launch lost the exit status of a node that ended cleanly: {excused}')
    died = [line for line in died if line not in excused]
    finished += excused
    assert len(started) >= nodes, text[-3000:]
    # a process that died: its own lines, whole (a hung teardown's native stacks, printed 4 s
    # into it, come well before the end of the launch's output)
    names = {m.group(1) for line in died if (m := re.search(r'\[(\S+)\]: process has died', line))}
    own = [line for line in text.splitlines() if any(line.startswith(f'[{name}]') for name in names)]
    assert not died and len(finished) == len(started), '\n'.join(own[-300:]) + '\n...\n' + text[-3000:]


def test_two_machines_in_two_namespaces_run_side_by_side_one_records_and_both_stop_cleanly_on_ctrl_c(
        cli_env, tmp_path):
    """Two launches in one ROS domain: mill1 (micromill_9axis) and mill2 (trt_5axis, recording).
    Each graph is alone in its namespace (nothing in the root, each clock heard by its own
    graph only); a goal to mill1 reaches mill1 only; mill2 publishes its robot_description,
    moves with a goal of its own and records it; Ctrl-C ends every node of both cleanly,
    mill2's bag closed. (One start-up of the two graphs for what were two tests: a launch in
    a namespace with a recording, and two machines side by side.) mill1 runs with a belief
    file (`identified:=`): its servos have it as their `belief` parameter. Both take a
    parameters file (`params_file:=`, LOADED_HOST_PARAMS) over the graph's own values."""
    bag = tmp_path / 'bag'
    belief = tmp_path / 'x_c.yaml'
    belief.write_text('axes:\n  x_c:\n    drive:\n      mass: 21.3\n      damping: 25.0\n')
    params = tmp_path / 'loaded_host.yaml'
    params.write_text(yaml.safe_dump(LOADED_HOST_PARAMS))
    mill1 = Launch(cli_env, tmp_path / 'mill1.log', 'machine:=micromill_9axis', 'namespace:=mill1',
                   f'identified:={belief}', f'params_file:={params}')
    mill2 = Launch(cli_env, tmp_path / 'mill2.log', 'machine:=trt_5axis', 'namespace:=mill2', f'record:={bag}',
                   f'params_file:={params}')
    try:
        side_by_side((wait_ready, cli_env, '/mill1', mill1), (wait_ready, cli_env, '/mill2', mill2))
        _, states1, states2 = side_by_side(
            (echo_until, cli_env, '/mill2/robot_description', 'std_msgs/msg/String', lambda m: '<robot' in m['data'],
             mill2, 60.0),
            (echo_until, cli_env, '/mill1/joint_states', 'sensor_msgs/msg/JointState', bool, mill1, 60.0, False),
            (echo_until, cli_env, '/mill2/joint_states', 'sensor_msgs/msg/JointState', bool, mill2, 60.0, False))
        assert states1['name'] == ['x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f']
        assert states2['name'] == ['x', 'y', 'z', 'a', 'c']
        listed, believed, timeout, stall_limit, *infos = side_by_side(
            (ros2, cli_env, 'topic', 'list'), (ros2, cli_env, 'param', 'get', '/mill1/servo_coarse', 'belief'),
            (ros2, cli_env, 'param', 'get', '/mill1/hw_sim', 'command_timeout'),
            (ros2, cli_env, 'param', 'get', '/mill2/trajectory', 'stall_limit'),
            *((ros2, cli_env, 'topic', 'info', '-v', f'{ns}/clock') for ns in ('/mill1', '/mill2')))
        assert str(belief) in believed, believed
        assert (timeout.strip(), stall_limit.strip()) == ('Double value is: 15.0', 'Double value is: 6.0')
        topics = listed.split()
        assert '/clock' not in topics and '/joint_states' not in topics, topics     # nothing in the root
        for ns, info in zip(('/mill1', '/mill2'), infos):          # each clock heard by its own graph only
            readers = [line for line in info.splitlines() if line.startswith('Node namespace:')]
            assert readers and all(line.split(':', 1)[1].strip() == ns for line in readers), info
        goal = '{joint_names: [x_c], points: [{positions: [0.002]}]}'
        assert send_goal_and_follow(cli_env, '/mill1', mill1, goal, 1) == [1, 2, 4]
        # mill2's own goal: 2 subscribers, the trajectory node and the recorder; its goal status
        # as it stood before (mill1's goal ended) is the latched list its follower gets first
        other = []
        statuses = send_goal_and_follow(cli_env, '/mill2', mill2, '{joint_names: [x], points: [{positions: [0.01]}]}',
                                        2, before=other)
        assert len(other) == 1 and not other[0].get('status_list'), other    # the goal went to mill1 only
        assert statuses == [1, 2, 4], statuses         # accepted, executing, succeeded
        status2, seconds = mill2.interrupt()
        status1, _ = mill1.interrupt()
    finally:
        mill1.close()
        mill2.close()
    print(f'mill2 launch ended {seconds:.2f} s after Ctrl-C (status {status2})')
    assert_ended_cleanly(mill2, status2, 5)       # hw_sim, servo, trajectory, contour_error, recorder
    assert_ended_cleanly(mill1, status1, 6)       # hw_sim, 2 servos, dual_stage, trajectory, contour_error
    with Bag(bag) as recorded:                        # the indexed reader: summary and metadata present
        assert recorded.topics['/mill2/joint_states'].count > 0
        assert recorded.custom_data['machine_ctrl.namespace'] == '/mill2'
        assert not [t for t in recorded.topics if t.startswith('/mill1/')], list(recorded.topics)   # its own only


def _diagnostic_values(message) -> dict:
    """name -> {key: value} of a DiagnosticArray as `ros2 topic echo` prints it."""
    return {status['name']: {kv['key']: kv['value'] for kv in status.get('values') or []}
            for status in message.get('status') or []}


def test_a_killed_servo_is_respawned_and_a_reset_continues(cli_env, tmp_path):
    launch = Launch(cli_env, tmp_path / 'launch.log', 'machine:=trt_5axis', 'namespace:=mill3')
    started = re.compile(r'\[servo_node-\d+\]: process started with pid \[(\d+)\]')
    try:
        wait_ready(cli_env, '/mill3', launch)
        first = started.findall(launch.text())
        assert len(first) == 1, launch.text()[-3000:]
        os.kill(int(first[0]), signal.SIGKILL)
        # the machine faults on the servo's missing commands (launch starts its successor only
        # after hw_sim's command_timeout); or, where hw_sim's own process was starved longer
        # than that meanwhile (a busy machine), on that stall, which it checks first: either
        # way a fault that only a reset leaves. Then, in the /diagnostics after that fault:
        # respawned by launch; hw_sim re-sends the held step until the new servo answers it.
        # (One reader of /diagnostics for both, in order: the second look starts with the
        # message after the fault's.)
        faulted = threading.Event()
        seen: dict = {}

        def faults_then_answers_the_held_step(message) -> bool:
            if not faulted.is_set():
                if _diagnostic_values(message).get('hw_sim', {}).get('fault', '').startswith(
                        ('missing command for ', 'hw_sim stalled: ')):
                    faulted.set()
                return False
            for name, values in _diagnostic_values(message).items():
                seen.setdefault(name, {}).update(values)
            servo, hw = seen.get('servo_coarse', {}), seen.get('hw_sim', {})
            return len(started.findall(launch.text())) == 2 and 'answered_step' in servo \
                and servo['answered_step'] == hw.get('step')
        echo_until(cli_env, '/mill3/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray',
                   faults_then_answers_the_held_step, launch, 2 * READY_TIMEOUT, latched=False)
        assert faulted.is_set()
        answer = ros2(cli_env, 'service', 'call', '/mill3/hw_sim/reset', 'std_srvs/srv/Trigger')
        assert 'success=True' in answer, answer
        # the trajectory node leaves its fault once hw_sim's healthy /diagnostics reach it: a
        # goal sent before that is refused
        echo_until(cli_env, '/mill3/trajectory/status', 'diagnostic_msgs/msg/DiagnosticStatus',
                   lambda m: m.get('message') == 'idle', launch, READY_TIMEOUT)
        goal = '{joint_names: [y], points: [{positions: [0.005]}]}'
        assert send_goal_and_follow(cli_env, '/mill3', launch, goal, 1) == [1, 2, 4]
        status, _ = launch.interrupt()
    finally:
        launch.close()
    assert status == 0, launch.text()[-3000:]


def test_a_belief_file_that_cannot_be_read_stops_the_launch_before_any_node_starts(cli_env, tmp_path):
    """`identified:=` with a file that is not there: the launch ends with the reason naming
    it, and no node was started (as `machine-ctrl bringup --identified` refuses)."""
    missing = tmp_path / 'missing.yaml'
    result = subprocess.run([str(ROS2), 'launch', 'machine_ctrl', 'bringup.launch.py', f'identified:={missing}'],
                            env=cli_env, capture_output=True, text=True, timeout=EXIT_TIMEOUT, start_new_session=True)
    text = result.stdout + result.stderr
    assert result.returncode != 0 and str(missing) in text, text[-3000:]
    assert 'process started' not in text, text[-3000:]


@pytest.mark.parametrize('value, reason', [('2', 'real_time_factor: must be in (0, 1], got 2.0'),
                                           ('fast', "paced:='fast' must be a real-time factor in (0, 1]")])
def test_a_bad_paced_factor_stops_the_launch_before_any_node_starts(cli_env, value, reason):
    result = subprocess.run([str(ROS2), 'launch', 'machine_ctrl', 'bringup.launch.py', f'paced:={value}'],
                            env=cli_env, capture_output=True, text=True, timeout=EXIT_TIMEOUT, start_new_session=True)
    text = result.stdout + result.stderr
    assert result.returncode != 0 and reason in text, text[-3000:]
    assert 'process started' not in text, text[-3000:]
