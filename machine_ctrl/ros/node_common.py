"""Plumbing shared by every node: machine parameter, wall-clock timers, raw subscriptions
to the per-step states and the reference chunks (decoded by machine_ctrl.recording.cdr), spinning
one or several nodes (one process per node, or all in one) with clean shutdown."""
from __future__ import annotations

import sys
import time

import rclpy
from rclpy.task import Future
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl.recording.cdr import ChunkDecoder, JointStateDecoder
from machine_ctrl.model.config import DEFAULT_MACHINE, MachineConfig, load_machine
from machine_ctrl.ros.messages import REFERENCE_QOS, STEP_QOS, InvalidMessage, parse_chunk_bytes
from machine_ctrl.model.errors import ConfigError

# Events executor: several times faster than SingleThreadedExecutor here (bench/RESULTS.md).
try:
    from rclpy.experimental.events_executor import EventsExecutor as DefaultExecutor
except ImportError:  # pragma: no cover - older rclpy
    DefaultExecutor = SingleThreadedExecutor


def declare(node: Node, name: str, default, description: str = ''):
    from rcl_interfaces.msg import ParameterDescriptor
    return node.declare_parameter(name, default, ParameterDescriptor(description=description)).value


def machine_parameter(node: Node) -> MachineConfig:
    """The `machine` parameter (name or YAML path), loaded; a bad config ends the node with
    one line on the log."""
    name = declare(node, 'machine', DEFAULT_MACHINE, 'machine name or path of its YAML file')
    try:
        return load_machine(name)
    except ConfigError as exc:
        node.get_logger().fatal(str(exc))
        raise SystemExit(2) from None


def use_sim_time(node: Node) -> None:
    """Every node runs on hw_sim's clock (design.md "Time")."""
    if not node.has_parameter('use_sim_time'):
        node.declare_parameter('use_sim_time', True)
    node.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, True)])


def wall_timer(node: Node, period: float, callback):
    """A timer on the steady clock: runs whether or not sim time advances."""
    return node.create_timer(period, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


def spin(nodes, executor=None) -> None:
    """Spin until Ctrl-C / SIGTERM (rclpy's handlers shut the context down). Not
    executor.spin(): with rclpy 7.1's EventsExecutor, spinning without a timeout never fires
    timers nor callbacks for other processes' messages, and ignores SIGINT/SIGTERM (checked
    here). spin_until_future_complete on a future that never completes, with a finite
    timeout, dispatches events inside the executor without returning to Python per event."""
    executor = executor or DefaultExecutor()
    for node in nodes:
        executor.add_node(node)
    logger = nodes[0].get_logger()
    never = Future()
    try:
        while rclpy.ok():
            try:
                executor.spin_until_future_complete(never, timeout_sec=1.0)
            except (KeyboardInterrupt, ExternalShutdownException):
                raise
            except Exception as exc:  # noqa: BLE001 - a node never dies from a callback error
                logger.error(f'callback failed: {type(exc).__name__}: {exc}', throttle_duration_sec=1.0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        executor.shutdown()
        if rclpy.ok():
            rclpy.try_shutdown()


def subscribe_joint_states(node: Node, topic: str, on_state, refuse):
    """A raw subscription to a per-step JointState topic, decoded by machine_ctrl.recording.cdr (~4 us
    instead of rclpy's ~14 us a message, bench/wire_rate.py): `on_state(JointStateData)`
    for each message, `refuse(reason)` for bytes that are not a JointState."""
    decoder = JointStateDecoder()

    def take(data: bytes) -> None:
        try:
            msg = decoder.decode(data)
        except InvalidMessage as exc:
            refuse(str(exc))
            return
        on_state(msg)
    return node.create_subscription(JointState, topic, take, STEP_QOS, raw=True)


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


def main_for(node_class):
    """`main()` of a node executable: `ros2 run machine_ctrl <exe> --ros-args ...`."""
    def main(args=None) -> int:
        rclpy.init(args=sys.argv if args is None else args)
        try:
            node = node_class()
        except SystemExit as exc:
            rclpy.try_shutdown()
            return int(exc.code or 1)
        spin([node])
        return 0
    return main


class Rejections:
    """Counts refused messages and keeps the last reason (for /diagnostics)."""

    def __init__(self, node: Node):
        self.logger = node.get_logger()
        self.count = 0
        self.last = ''

    def add(self, what: str, reason: str) -> None:
        self.count += 1
        self.last = f'{what}: {reason}'
        self.logger.warning(f'rejected {what}: {reason}', throttle_duration_sec=1.0)


class StepResponder:
    """Answers each /joint_states step exactly once (design.md "Time").

    `ready(step)` says whether the inputs for the step are there; the responder waits for
    them up to `timeout` s (wall), then answers anyway (`compute` handles the gap) — but
    only once `streaming()` says every input stream has delivered at least once: an input
    that never started is waited for indefinitely, so a lock-step run does not depend on
    how fast the graph came up.
    `compute(step, state)` returns the answer message, or None to give no answer. A repeated
    stamp (hw_sim re-sends while waiting) gets the cached answer again; older stamps are
    ignored. A stamp more than one step ahead of the newest step seen is refused
    (InvalidMessage) unless it comes twice in a row: hw_sim never skips a step and re-sends a
    state it waits on, so a stray message with a future stamp cannot make the node skip the
    real steps (and stop the machine on missing commands).
    """

    def __init__(self, node: Node, publisher, ready, compute, timeout: float, streaming):
        self.publisher, self.ready, self.compute, self.timeout = publisher, ready, compute, timeout
        self.streaming = streaming
        self.pending = None
        self.pending_since = 0.0
        self.answered = None
        self.newest = None                   # newest step taken
        self.skip_candidate = None           # a step ahead of newest + 1, seen once
        wall_timer(node, min(0.02, timeout / 5), self._on_timer)

    @property
    def answered_step(self) -> int:
        return self.answered[0] if self.answered else 0

    def on_state(self, step: int, msg) -> None:
        if self.answered is not None and step <= self.answered[0]:
            if step == self.answered[0]:
                self.publisher.publish(self.answered[1])
            return
        if self.newest is not None and step > self.newest + 1 and step != self.skip_candidate:
            self.skip_candidate = step
            raise InvalidMessage(f'state of step {step} skips ahead of step {self.newest + 1} '
                                 '(taken only if it comes again)')
        self.newest = step if self.newest is None else max(self.newest, step)
        self.skip_candidate = None
        if self.pending is None or self.pending[0] != step:     # a re-send keeps its first arrival
            self.pending_since = time.monotonic()
        self.pending = (step, msg)
        self.poke()

    def poke(self, give_up: bool = False) -> None:
        """Answer the pending step if its inputs are there (or when giving up on them)."""
        if self.pending is None or not (give_up or self.ready(self.pending[0])):
            return
        step, msg = self.pending
        self.pending = None
        answer = self.compute(step, msg)
        if answer is not None:
            self.answered = (step, answer)
            self.publisher.publish(answer)

    @property
    def waiting(self) -> bool:
        return self.pending is not None

    def _on_timer(self) -> None:
        if (self.pending is not None and self.streaming()
                and time.monotonic() - self.pending_since > self.timeout):
            self.poke(give_up=True)
