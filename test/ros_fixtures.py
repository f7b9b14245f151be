"""pytest fixtures that keep ROS tests isolated (registered by conftest.py's pytest_plugins).

Why: DDS discovery is machine-wide. Two pytest sessions (two checkouts, CI beside a
developer, xdist workers) in the same ROS domain would see each other's nodes, and a
stray message answers the wrong test. So each session leases a domain id of its own
(an flock under /tmp, see machine_ctrl.app.processes.reserve_ros_domain) and keeps
discovery on localhost.

Nothing here imports rclpy at module level and no fixture is autouse: a session that runs
no ROS test pays nothing. A ROS test asks for ``ros_env`` (directly or through
``rclpy_context``/``ros_supervisor``) before it initialises rclpy.
"""
import contextlib
import io
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from machine_ctrl import contract, shared_memory
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain

_ROS_VARIABLES = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS',
                  'ROS_LOCALHOST_ONLY', 'AMENT_PREFIX_PATH')


def _rclpy_already_initialised():
    """rclpy reads ROS_DOMAIN_ID when a context is initialised; a context made before the
    variables are set would sit in the shared default domain. Checked without importing
    rclpy, so that this costs nothing when rclpy is unused."""
    rclpy = sys.modules.get('rclpy')
    return rclpy is not None and rclpy.ok()


@pytest.fixture(scope='session')
def ros_env():
    """Lease a ROS domain id for this test session, put it, ROS_AUTOMATIC_DISCOVERY_RANGE=
    LOCALHOST and AMENT_PREFIX_PATH (default sys.prefix) into os.environ for the
    in-process nodes, and return the same environment as a dict for child processes.
    os.environ is restored and the lease released at the end of the session. Fast DDS port
    files left empty (machine_ctrl.shared_memory) are removed first: this session's own
    participants would wait on one forever."""
    shared_memory.clean()
    if _rclpy_already_initialised():
        raise RuntimeError('rclpy was initialised before the ros_env fixture set ROS_DOMAIN_ID; '
                           'request ros_env (or rclpy_context) in every test that uses ROS')
    saved = {name: os.environ.get(name) for name in _ROS_VARIABLES}
    with reserve_ros_domain() as lease:
        env = isolated_ros_env(lease.domain_id)
        for name in _ROS_VARIABLES:
            if name in env:
                os.environ[name] = env[name]
            else:
                os.environ.pop(name, None)
        try:
            yield dict(env)
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
            left = ros2_daemons(lease.domain_id)
            for pid in left:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
    if left:
        raise RuntimeError(f'a ros2 daemon of this session (domain {lease.domain_id}) was left running, pid '
                           f'{left} (killed now): a test that runs a ros2 verb which starts one (topic echo, '
                           f'topic list, param get, ...) stops it at its end (`ros2 daemon stop`) or passes '
                           f'--no-daemon')


def ros2_daemons(domain_id: int) -> list[int]:
    """The pids of ros2 daemons serving ROS domain `domain_id` (the ros2 command line starts
    one, detached, at the first verb that asks the graph through it; it outlives the test
    and stays a participant of the domain until stopped). Its command line is
    `python -c ... --name ros2-daemon --ros-domain-id N ...`."""
    pids = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            argv = (proc / 'cmdline').read_bytes().split(b'\0')
        except OSError:                      # ended meanwhile, or not ours to read
            continue
        if b'ros2-daemon' in argv and any(argv[i] == b'--ros-domain-id' and argv[i + 1] == str(domain_id).encode()
                                          for i in range(len(argv) - 1)):
            pids.append(int(proc.name))
    return pids


@contextlib.contextmanager
def private_context(ros_env):
    """A fresh, initialised rclpy Context in the domain of ``ros_env``, shut down on exit
    whatever happened. Its own context (not the default one) so that a test cannot leak
    nodes or state into the next; rclpy's signal handlers are left alone (pytest owns
    SIGINT). For fixtures of a wider scope than ``rclpy_context``."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env['ROS_DOMAIN_ID']))
    try:
        yield context
    finally:
        context.try_shutdown()


@pytest.fixture
def rclpy_context(ros_env):
    """``private_context`` for one test. Destroy your nodes before the test ends, or use
    ``ros_node``."""
    with private_context(ros_env) as context:
        yield context


@pytest.fixture
def ros_node(rclpy_context):
    """Factory ``ros_node(name, **node_kwargs)`` for rclpy nodes on ``rclpy_context``;
    every node made is destroyed at teardown, before the context is shut down."""
    from rclpy.node import Node

    nodes = []

    def make(name, **kwargs):
        node = Node(name, context=rclpy_context, **kwargs)
        nodes.append(node)
        return node

    try:
        yield make
    finally:
        for node in reversed(nodes):
            node.destroy_node()


@pytest.fixture
def ros_supervisor(ros_env, tmp_path):
    """A Supervisor whose children run in the session's domain, logging to
    ``tmp_path/logs/<name>.log``; every child (and its process group) is stopped at
    teardown, also when the test fails."""
    with Supervisor(ros_env, log_dir=tmp_path / 'logs', stop_timeout=3.0) as supervisor:
        yield supervisor


class ProgressReporter:
    """A test's reader as a recorder: it reports on /recorder/progress the newest step it
    holds of every stream it reads, and hw_sim, started with `recorder_window` W, never runs
    more than W steps ahead of it. So no reliable keep-last queue overflows behind a test
    thread that falls behind (the graph waits for it, as for the recorder); holding only
    delays a lock-step run, it never changes it."""

    WINDOW = 50          # steps; well inside the per-step publishers' queues (contract.STEP_QOS)

    def __init__(self, node, clock):
        from builtin_interfaces.msg import Time

        from machine_ctrl.ros.node_common import qos
        self.clock, self.time_type, self.reported = clock, Time, -1
        self.publisher = node.create_publisher(Time, contract.RECORDER_PROGRESS.name,
                                               qos(contract.PROGRESS_QOS))

    def announce(self) -> None:
        """Nothing held yet (step -1), as a recorder says at its start: hw_sim, once it has this,
        stays at step 0 (re-sending it) until the first report of a step held."""
        sec, nanosec = self.clock.split(-1)
        self.publisher.publish(self.time_type(sec=sec, nanosec=nanosec))

    def report(self, step: int) -> None:
        """Every stream is held up to `step` (called from the reader's callbacks)."""
        if step > self.reported:
            self.reported = step
            sec, nanosec = self.clock.split(step)
            self.publisher.publish(self.time_type(sec=sec, nanosec=nanosec))


def on_disk(path, topic: str | None = None) -> int:
    """Messages (of `topic`, or all) in the complete chunks of a bag file being written: what a
    kill now would not lose. Counted with the mcap package's own stream reader, not with the
    salvage that ``machine-ctrl record --recover`` (under test) uses: the records in order up
    to the first one the file does not hold whole."""
    import struct
    from pathlib import Path

    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk
    path = Path(path)
    data = path.read_bytes() if path.exists() else b''
    source, channels, count = io.BytesIO(data), {}, 0
    try:
        for record in StreamReader(source, emit_chunks=True).records:
            # a chunk is yielded only once its whole record is read; channels may come in one
            for r in breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]:
                if isinstance(r, Channel):
                    channels[r.id] = r.topic
                elif isinstance(r, Message) and isinstance(record, Chunk):
                    count += topic is None or channels.get(r.channel_id) == topic
    except (EndOfFile, struct.error):            # a short read: what the file holds ends mid-record
        assert source.tell() == len(data)        # nothing else is taken for the end
    return count


# Fast DDS's own log lines: its default consumer writes them to stdout, coloured, so they
# start with an escape sequence, which no YAML line of `ros2 topic echo` does (a loaded run
# saw "[RTPS_TRANSPORT_SHM Error] Failed init_port ..." inside an echoed message)
FASTDDS_LOG = '\x1b['


def without_fastdds_log(text: str) -> str:
    """`ros2 topic echo`'s output without Fast DDS's log lines."""
    return ''.join(line for line in text.splitlines(keepends=True) if not line.startswith(FASTDDS_LOG))


def wait_until(condition, what: str, timeout: float = 300.0) -> None:
    """Poll `condition` until it holds; the timeout only bounds a failure (a planner process
    may first load, or after a change to its source compile, its numba kernel: seconds to a
    minute on a loaded machine)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f'no {what} within {timeout} s'
        time.sleep(0.01)
