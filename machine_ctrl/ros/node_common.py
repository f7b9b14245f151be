"""Plumbing shared by every node (parameters: machine_ctrl.ros.node_parameters): wall-clock timers, raw subscriptions
to the per-step states and the reference chunks (decoded by machine_ctrl.recording.cdr), spinning
one or several nodes (one process per node, or all in one) with clean shutdown."""
from __future__ import annotations

import contextlib
import faulthandler
import gc
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings

import rclpy
from rclpy.task import Future
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl import contract, shared_memory
from machine_ctrl.control.stepping import StepAnswerer
from machine_ctrl.diagnostics import Rejections
from machine_ctrl.recording.cdr import ChunkDecoder, JointStateDecoder
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.local_bus import BUS, subscribe_raw
from machine_ctrl.ros.messages import REFERENCE_QOS, STEP_QOS, InvalidMessage, parse_chunk_bytes

# Events executor: several times faster than SingleThreadedExecutor here (bench/RESULTS.md).
try:
    from rclpy.experimental.events_executor import EventsExecutor as DefaultExecutor
except ImportError:  # pragma: no cover - older rclpy
    DefaultExecutor = SingleThreadedExecutor


def use_sim_time(node: Node, refuse=None) -> None:
    """A node on the simulated clock (its parameter table's sim_time) runs on hw_sim's clock
    (design.md "Time"). A clock message that is no time (negative seconds: rclpy's TimeSource
    raises on it, and the node's log showed its exception; nanosec outside [0, 1e9)) is
    refused with the reason before rclpy's TimeSource sees it: `refuse(reason)` (the node's
    count of refused messages), else a warning on its log; the node's clock keeps its time."""
    from rclpy.time_source import TimeSource
    if not node.has_parameter('use_sim_time'):
        node.declare_parameter('use_sim_time', True)
    node.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, True)])
    if refuse is None:
        def refuse(reason: str) -> None:
            node.get_logger().warning(f'rejected clock: {reason}', throttle_duration_sec=1.0)
    for subscription in node.subscriptions:          # the TimeSource's, just made
        if isinstance(getattr(subscription.callback, '__self__', None), TimeSource):
            subscription.callback = _checked_clock(subscription.callback, refuse)


def _checked_clock(take, refuse):
    def on_clock(msg) -> None:
        stamp = msg.clock
        try:
            contract.join_ns(stamp.sec, stamp.nanosec)
        except InvalidMessage as exc:
            refuse(str(exc))
            return
        if stamp.sec < 0:
            refuse(f'stamp {stamp.sec} s {stamp.nanosec} ns is before time 0')
            return
        take(msg)
    return on_clock


def wall_timer(node: Node, period: float, callback):
    """A timer on the steady clock: runs whether or not sim time advances."""
    return node.create_timer(period, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


# assumed: 0.1 s between returns to Python bounds the reaction to SIGINT/SIGTERM while no
# callback runs (a busy node reacts at its next callback), far inside the 5 s launch waits
# before it escalates; one return per 0.1 s costs nothing measurable beside the per-step callbacks.
SIGNAL_POLL = 0.1          # s (wall)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# assumed: a node's shutdown (executor, nodes, context, interpreter exit) takes well under 1 s
# idle and a few s on a loaded 2-core machine; 8 s stays below launch's escalation to
# SIGKILL (sigterm_timeout + sigkill_timeout, 5 s each), so a hang leaves its stacks in the log.
SHUTDOWN_LIMIT = 8.0       # s (wall)
# assumed: half the limit, so that py-spy (~1.6 s to attach and walk the stacks on a loaded
# 2-core machine) is done before the process is ended at SHUTDOWN_LIMIT.
NATIVE_STACKS_AFTER = 4.0  # s (wall)


_early_signals: list[int] = []     # SIGINT / SIGTERM received before spin() began


def init(args=None, **kwargs) -> None:
    """rclpy.init for a node process, without rclpy's signal handlers: SIGINT and SIGTERM
    are :func:`spin`'s (rclpy's raise KeyboardInterrupt wherever the main thread happens to
    be, executor.shutdown included). One that comes while the nodes are being made is
    kept, and spin() then shuts down at once."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, lambda signum, _frame: _early_signals.append(signum))
    report_stacks_on_signal()
    rclpy.init(args=sys.argv if args is None else args, signal_handler_options=SignalHandlerOptions.NO, **kwargs)


def report_stacks_on_signal() -> None:
    """Every thread's stack on stderr at contract.STACKS_SIGNAL, the process going on."""
    faulthandler.register(contract.STACKS_SIGNAL, all_threads=True)


def spin(nodes, executor=None) -> None:
    """Spin until SIGINT / SIGTERM (Ctrl-C, `ros2 launch` shutting down, a supervisor) or the
    context's shutdown, then shut down cleanly: further signals ignored (for the rest of the
    process: spin is the end of a node process), executor shut down, nodes destroyed,
    context shut down — no traceback — and the process ends, exit 0 (:func:`end_process`:
    spin does not return); a teardown that hangs is reported and ended
    (:func:`bounded_teardown`).

    Not executor.spin(): with rclpy 7.1's EventsExecutor, spinning without a timeout never
    fires timers nor callbacks for other processes' messages. spin_until_future_complete on
    the stop future, with a finite timeout (:data:`SIGNAL_POLL`), dispatches events inside
    the executor without returning to Python per event; the signal handlers (run by Python
    in the main thread, at the latest when that call returns) complete the future.

    Several nodes (a single-process graph): the per-step streams between them go through
    this process's local bus (machine_ctrl.ros.local_bus), drained by `executor`."""
    executor = executor or DefaultExecutor()
    for node in nodes:
        executor.add_node(node)
    logger = nodes[0].get_logger()
    stop = Future()

    def request_stop(signum, _frame) -> None:
        if not stop.done():
            logger.info(f'{signal.Signals(signum).name}: shutting down')
            stop.set_result(signum)

    for sig in STOP_SIGNALS:
        signal.signal(sig, request_stop)
    if _early_signals:
        request_stop(_early_signals[0], None)
    log_runtime_warnings(logger)
    # Everything made so far (modules, nodes, models) lives as long as the process: moved out of
    # the collector's view, a full collection scans only what the callbacks made since. It took
    # 26-50 ms a few times a minute in a one-process graph (hw_sim's paced steps slipped that
    # long, bench/RESULTS.md "Paced"), now ~4 ms. The garbage of building them goes first.
    gc.collect()
    gc.freeze()
    if len(nodes) > 1:        # nodes of one process exchange the per-step streams in it
        readers = BUS.start(executor, nodes)
        logger.info(f'local bus: {readers} readers of the per-step streams take what the nodes of this process '
                    'send them without DDS')
    try:
        while rclpy.ok() and not stop.done():
            try:
                executor.spin_until_future_complete(stop, timeout_sec=SIGNAL_POLL)
            except ExternalShutdownException:
                break
            except Exception as exc:  # noqa: BLE001 - a node never dies from a callback error
                logger.error(f'callback failed: {type(exc).__name__}: {exc}', throttle_duration_sec=1.0)
    finally:
        # A second signal (a terminal's Ctrl-C reaches every process of the group, then
        # launch sends its own) must not cut the shutdown short, nor raise KeyboardInterrupt
        # while the interpreter exits: ignored from here to the end of the process.
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)
        BUS.stop()
        teardown(executor, nodes)
    end_process(0)          # only after a stop; an exception out of the loop goes on (its traceback)


def log_runtime_warnings(logger) -> None:
    """Every RuntimeWarning of the process goes to `logger` as an error, each time (Python
    prints one per source line to stderr, once). rclpy warns so when a service's answer is
    lost: "failed to send response (timeout): client will not receive response", when
    rmw_fastrtps's response writer has not matched the client's response reader within its
    max_blocking_time (100 ms by default; the client, which may have discovered the service
    first, then waits for ever: ros2/rmw_fastrtps#704). Such a loss must be in the node's log."""
    warnings.filterwarnings('always', category=RuntimeWarning)
    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, RuntimeWarning):
            logger.error(f'{category.__name__}: {message} ({filename}:{lineno})')
        else:
            shown(message, category, filename, lineno, file, line)
    warnings.showwarning = show


EXIT_NODE = '_exiting_{pid}'    # hidden (leading underscore): `ros2 node list` leaves it out


def keep_participant(context) -> Node:
    """A node that is never destroyed, so that destroying the process's own nodes never deletes
    its DDS participant: in Fast DDS 2.14.5 (the Jazzy wheels) deleting the participant first
    waits for its discovery callbacks to end (DomainParticipantImpl::set_listener, no time
    limit), and that wait, built against glibc 2.28, computes a negative deadline: its
    pthread_cond_timedwait fails at once without releasing the mutex a callback running then
    needs to finish, so the process spins for ever, holding the GIL (eProsima/Fast-DDS#6513;
    seen when two graphs of ~11 processes stop at once: test_launch, run89, run107, 2026-12-07).
    The nodes' own entities and the nodes themselves are still destroyed, and announced; the
    participant ends with the process (:func:`end_process`), and other processes drop it when
    its lease runs out (20 s), its endpoints already gone."""
    return Node(EXIT_NODE.format(pid=os.getpid()), context=context, use_global_arguments=False,
                enable_rosout=False, start_parameter_services=False,
                parameter_overrides=[Parameter('start_type_description_service', Parameter.Type.BOOL, False)])


EXIT_LINE = 'process ends: exit status {status}'


def end_process(status: int):
    """End the process now with `status`, its output flushed, without Python's or C++'s exit
    handlers: they would delete the DDS participant that :func:`keep_participant` keeps (the
    node's deleter, Fast DDS's DomainParticipantFactory destructor; the same wait). Its
    shared-memory segment (~0.5 MB) is removed first, as deleting the participant would
    (machine_ctrl.shared_memory.remove_own_segments). Its last line on stderr is
    :data:`EXIT_LINE`: the status in the node's own output, where `ros2 launch` may lose it
    (README "For ROS users": a child reaped by launch's own signal, reported as code 255)."""
    import ctypes
    import logging
    shared_memory.remove_own_segments()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)          # C stdio (rcutils' console output)
    with contextlib.suppress(Exception):        # after every other output
        print(EXIT_LINE.format(status=status), file=sys.stderr, flush=True)
    os._exit(status)


def teardown(executor, nodes) -> None:
    """The end of a node process but its exit (:func:`end_process`): the executor shut down,
    a node kept (:func:`keep_participant`), the process's nodes destroyed, the context shut
    down; bounded (:func:`bounded_teardown`)."""
    with bounded_teardown():
        executor.shutdown()
        if nodes[0].context.ok():           # not shut down from elsewhere (a node can be made)
            keep_participant(nodes[0].context)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


@contextlib.contextmanager
def bounded_teardown():
    """The end of a node process: ROS entities, nodes and context destroyed inside. One that
    hangs (seen in test_launch's two graphs stopped at once on a loaded machine, inside rclpy's
    destroy of a service or a node, i.e. in rmw / Fast DDS: run89, run107) prints its native
    stacks after :data:`NATIVE_STACKS_AFTER` (where py-spy is installed), every Python
    thread's stack at :data:`SHUTDOWN_LIMIT`, and ends the process there, exit 1."""
    faulthandler.dump_traceback_later(SHUTDOWN_LIMIT, exit=True)
    native_stacks = native_stacks_later(NATIVE_STACKS_AFTER)
    try:
        yield
    finally:
        if native_stacks is not None:     # done: the watcher ends (or finishes its dump)
            native_stacks.stdin.close()
            native_stacks.wait()


def native_stacks_later(delay: float) -> subprocess.Popen | None:
    """Where py-spy is installed (beside this interpreter or on PATH; the test extras bring
    it): a watcher that prints this process's native and Python stacks on stderr
    (`py-spy dump --native`) unless its stdin is closed within `delay` s. For shutdowns that
    hang inside rcl / rmw / Fast DDS: faulthandler shows only the Python caller, and no Python
    thread can run while rclpy holds the GIL in such a call; the watcher is another process.
    None without py-spy. Needs ptrace permission on this process (root, or
    kernel.yama.ptrace_scope 0); py-spy says so on stderr when refused."""
    where = os.pathsep.join((os.path.dirname(sys.executable), os.environ.get('PATH', '')))
    py_spy = shutil.which('py-spy', path=where)
    if py_spy is None:
        return None
    # `timeout` ends cat after `delay` s with status 124; cat ends at once (status 0) on the
    # EOF of a closed stdin, also when this process exits: then the watcher exits 0
    script = 'timeout "$0" cat > /dev/null; [ $? -ne 124 ] || exec "$1" dump --native --pid "$2"'
    # its own session: a second Ctrl-C to the terminal's process group does not end it
    return subprocess.Popen(['sh', '-c', script, f'{delay:g}', py_spy, str(os.getpid())],
                            stdin=subprocess.PIPE, stdout=sys.stderr.fileno(), stderr=sys.stderr.fileno(),
                            start_new_session=True)


# the newest (bytes, JointStateData) decoded by any subscribe_joint_states reader of this
# process: the local bus hands one bytes object to every reader of a message, so readers
# served one after another take the first one's decoding (an immutable named tuple of
# tuples): the helix's state goes to the loop's three readers of /joint_states, decoded
# once; contour_error, served after the loop's answers were decoded, decodes it again.
# One tuple, assigned at once: a reader in another thread sees a matching pair or none.
_last_decoded: tuple = (None, None)


def subscribe_joint_states(node: Node, topic: str, on_state, refuse, later: bool = False):
    """A raw subscription to a per-step JointState topic, decoded by machine_ctrl.recording.cdr (~4 us
    instead of rclpy's ~14 us a message, bench/wire_rate.py): `on_state(JointStateData)`
    for each message, `refuse(reason)` for bytes that are not a JointState. Those of a
    writer in this process come through the local bus while it runs (local_bus.subscribe_raw;
    `later`: a reader outside the control loop), decoded once for the readers served one
    after another (:data:`_last_decoded`)."""
    decoder = JointStateDecoder()

    def take(data: bytes) -> None:
        global _last_decoded
        last_data, msg = _last_decoded
        if data is not last_data:
            try:
                msg = decoder.decode(data)
            except InvalidMessage as exc:
                refuse(str(exc))
                return
            _last_decoded = (data, msg)
        on_state(msg)
    return subscribe_raw(node, JointState, topic, take, STEP_QOS, later)


def subscribe_reference(node: Node, topic: str, clock, wanted, on_chunk, refuse):
    """A raw subscription to reference chunks (trajectory_msgs/JointTrajectory on the control
    grid), decoded by machine_ctrl.recording.cdr: `on_chunk(first_step, positions, velocities,
    accelerations)` with rows of the `wanted` axes, `refuse(reason)` for a chunk refused."""
    decoder = ChunkDecoder()

    def take(data: bytes) -> None:
        try:
            chunk = parse_chunk_bytes(clock, decoder, data, wanted)
        except InvalidMessage as exc:
            refuse(str(exc))
            return
        on_chunk(*chunk)
    return node.create_subscription(JointTrajectory, topic, take, REFERENCE_QOS, raw=True)


def qos(spec):
    """The rclpy profile of a contract QoS (machine_ctrl.ros.messages.qos), with its
    liveliness lease when it has one: automatic liveliness, asserted by DDS's own threads, so
    its readers learn within the lease that the writer's process is gone or stopped."""
    profile = ros_io.qos(spec)
    if spec.liveliness_lease > 0:
        from rclpy.duration import Duration
        from rclpy.qos import LivelinessPolicy
        profile.liveliness = LivelinessPolicy.AUTOMATIC
        profile.liveliness_lease_duration = Duration(nanoseconds=contract.seconds_to_ns(spec.liveliness_lease))
    return profile


def watch_liveliness(node: Node, msg_type, topic: str, spec, on_change, on_message=None):
    """A subscription to `topic` that asks for its writers' liveliness (`spec` must carry
    the lease the writers offer, or a longer one; a writer that offers none does not match):
    `on_change(alive)` with True when the first writer (again) asserts its liveliness and
    False when no writer is alive any more (lost within the lease: killed, stopped, hung, or
    gone). `on_message(msg)` takes the messages (default: none wanted, and none deserialized).

    A writer in this node's own process (the same DDS participant: a single-process graph)
    is alive while it exists: Fast DDS 2.14 reports such a writer not alive one lease after
    its last message although its liveliness is automatic (eProsima/Fast-DDS#6306; tested in
    test_liveliness.py), so a loss is not passed on while a writer of `topic` is in this
    process: its process cannot be lost without this one. Nor is it passed on later when
    that writer is destroyed after such a report (Fast DDS has nothing more to report: in
    the graphs here nodes are destroyed only at shutdown), nor while a local writer exists
    beside a remote one that is lost (not "no writer alive")."""
    from rclpy.event_handler import SubscriptionEventCallbacks

    def changed(info) -> None:
        if info.alive_count_change > 0 and info.alive_count == info.alive_count_change:
            on_change(True)
        elif info.alive_count_change < 0 and info.alive_count == 0:
            if not writer_in_process(node, subscription.topic_name):
                on_change(False)
    subscription = node.create_subscription(msg_type, topic, on_message or (lambda _data: None), qos(spec),
                                            event_callbacks=SubscriptionEventCallbacks(liveliness=changed),
                                            raw=on_message is None)
    return subscription


GUID_PREFIX = 12     # bytes of an endpoint's gid that name its DDS participant (RTPS GUID prefix)


def writer_in_process(node: Node, topic: str) -> bool:
    """Whether a writer of `topic` (fully qualified) is in `node`'s own DDS participant (its
    process): the graph's endpoints of this node (by its name: node names are unique in a
    graph) give the participant's GUID prefix."""
    me = (node.get_name(), node.get_namespace())
    own = {bytes(info.endpoint_gid[:GUID_PREFIX])
           for name, _types in node.get_publisher_names_and_types_by_node(*me)
           for info in node.get_publishers_info_by_topic(name) if (info.node_name, info.node_namespace) == me}
    return any(bytes(info.endpoint_gid[:GUID_PREFIX]) in own for info in node.get_publishers_info_by_topic(topic))


def main_for(node_class):
    """`main()` of a node executable: `ros2 run machine_ctrl <exe> --ros-args ...`."""
    def main(args=None) -> int:
        init(args)
        try:
            node = node_class()
        except SystemExit as exc:
            rclpy.try_shutdown()
            return int(exc.code or 1)
        spin([node])        # ends the process
    return main


def rejections(node: Node) -> Rejections:
    """The count of a node's refused messages and the last reason (for /diagnostics), each
    refusal warned on the node's log at most once a second."""
    logger = node.get_logger()
    return Rejections(lambda text: logger.warning(text, throttle_duration_sec=1.0))


# assumed: the responder's timer runs every 20 ms at most; 1 s between two of its runs means
# the process did not run (stopped, starved, or blocked in a call), long enough to matter to
# hw_sim's command_timeout (5 s by default) and far above a busy Python process's hiccups.
STALL_GAP = 1.0            # s (wall)


class StepResponder:
    """Answers each /joint_states step exactly once: machine_ctrl.control.stepping.StepAnswerer
    (the rules: caching, input timeout, refused skips) on the node's wall clock, answers
    published on `publisher`. A gap of more than :data:`STALL_GAP` between two runs of its
    timer is logged (a warning naming the gap and the step answered last): when hw_sim faults
    on this node's missing answer, its log tells a process that did not run from one that
    ran and heard nothing."""

    def __init__(self, node: Node, publisher, ready, compute, timeout: float, streaming):
        self.core = StepAnswerer(publisher.publish, ready, compute, timeout, streaming)
        self.poke = self.core.poke           # the core's, unwrapped: on the per-step path
        self.logger = node.get_logger()
        self._timer_at = None                # the first run has no gap: start-up is not a stall
        wall_timer(node, min(0.02, timeout / 5), self._on_timer)

    @property
    def answered_step(self) -> int:
        return self.core.answered_step

    def has_answered(self, step: int) -> bool:
        return self.core.has_answered(step)

    @property
    def waiting(self) -> bool:
        return self.core.waiting

    def on_state(self, step: int, msg) -> None:
        """InvalidMessage for a state that skips ahead (see StepAnswerer)."""
        self.core.on_state(step, msg, time.monotonic())

    def _on_timer(self) -> None:
        now = time.monotonic()
        gap, self._timer_at = now - (self._timer_at or now), now
        if gap > STALL_GAP:
            self.logger.warning(f'its process did not run for {gap:.1f} s (stopped, starved or blocked in a call); '
                                f'step answered last: {self.core.answered_step}')
        self.core.on_timer(now)
