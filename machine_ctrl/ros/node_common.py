"""Plumbing shared by every node (parameters: machine_ctrl.ros.node_parameters): wall-clock timers, raw subscriptions
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

from machine_ctrl.control.stepping import StepAnswerer
from machine_ctrl.diagnostics import Rejections
from machine_ctrl.recording.cdr import ChunkDecoder, JointStateDecoder
from machine_ctrl.ros.messages import REFERENCE_QOS, STEP_QOS, InvalidMessage, parse_chunk_bytes

# Events executor: several times faster than SingleThreadedExecutor here (bench/RESULTS.md).
try:
    from rclpy.experimental.events_executor import EventsExecutor as DefaultExecutor
except ImportError:  # pragma: no cover - older rclpy
    DefaultExecutor = SingleThreadedExecutor


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


def rejections(node: Node) -> Rejections:
    """The count of a node's refused messages and the last reason (for /diagnostics), each
    refusal warned on the node's log at most once a second."""
    logger = node.get_logger()
    return Rejections(lambda text: logger.warning(text, throttle_duration_sec=1.0))


class StepResponder:
    """Answers each /joint_states step exactly once: machine_ctrl.control.stepping.StepAnswerer
    (the rules: caching, input timeout, refused skips) on the node's wall clock, answers
    published on `publisher`."""

    def __init__(self, node: Node, publisher, ready, compute, timeout: float, streaming):
        self.core = StepAnswerer(publisher.publish, ready, compute, timeout, streaming)
        self.poke = self.core.poke           # the core's, unwrapped: on the per-step path
        wall_timer(node, min(0.02, timeout / 5), self._on_timer)

    @property
    def answered_step(self) -> int:
        return self.core.answered_step

    @property
    def waiting(self) -> bool:
        return self.core.waiting

    def on_state(self, step: int, msg) -> None:
        """InvalidMessage for a state that skips ahead (see StepAnswerer)."""
        self.core.on_state(step, msg, time.monotonic())

    def _on_timer(self) -> None:
        self.core.on_timer(time.monotonic())
