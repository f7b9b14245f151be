"""The caller's side of the trajectory node's command API (README "Node graph"): send tool
paths and joint goals, call the services, follow /trajectory/status. What another robot or
program does, packaged for `machine-ctrl send` / `move`, the demo and the graph tests.
Spins its own node in a background thread."""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from nav_msgs.msg import Path
from std_msgs.msg import Float64

from machine_ctrl import contract
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.model.config import MachineConfig



class Timeout(RuntimeError):
    pass


class MachineClient:
    def __init__(self, node, machine: MachineConfig):
        self.node, self.machine = node, machine
        self.clock = ros_io.StepClock.of(machine)
        self.statuses: list[DiagnosticStatus] = []
        node.create_subscription(DiagnosticStatus, contract.TRAJECTORY_STATUS.name, self.statuses.append,
                                 ros_io.qos(contract.LATCHED_READER_QOS))
        self.pub_path = node.create_publisher(Path, contract.PATH.name, ros_io.qos(contract.PATH.qos))
        self.pub_goal = node.create_publisher(JointTrajectory, contract.JOINT_GOAL.name, ros_io.qos(contract.JOINT_GOAL.qos))
        self.pub_override = node.create_publisher(Float64, contract.FEED_OVERRIDE.name, ros_io.qos(contract.FEED_OVERRIDE.qos))
        self._services = {}
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(node)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while self._running:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=2)
        self.executor.shutdown()

    # -- state -----------------------------------------------------------------------------
    def status(self) -> dict:
        """Values of the newest /trajectory/status ({} before the first)."""
        return {kv.key: kv.value for kv in self.statuses[-1].values} if self.statuses else {}

    def wait(self, predicate, what: str, timeout: float = 120.0, check=None) -> None:
        """Poll `predicate` until true; `check()` (e.g. a process supervisor's) runs between
        polls and may raise."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise Timeout(f'timed out after {timeout:g} s waiting for {what}; status {self.status()}')
            if check is not None:
                check()
            time.sleep(0.05)

    def states_seen(self, after: int, states) -> bool:
        """The statuses after the first `after` went through `states` in this order."""
        wanted = list(states)
        for status in self.statuses[after:]:
            if wanted and status.message == wanted[0]:
                wanted.pop(0)
        return not wanted

    def wait_states(self, after: int, states, timeout: float = 120.0, check=None) -> None:
        self.wait(lambda: self.states_seen(after, states), f'states {list(states)}', timeout, check)

    # -- commands --------------------------------------------------------------------------
    def send_path(self, cl, frame: str | None = None) -> None:
        self.pub_path.publish(ros_io.path_message(cl, frame or self.machine.workpiece_frame))

    def send_goal(self, names, points, times=None) -> None:
        """Joint goal: `points` hold values for `names`; `times` (s) earliest arrivals."""
        msg = JointTrajectory()
        msg.joint_names = list(names)
        for i, values in enumerate(points):
            point = JointTrajectoryPoint(positions=[float(v) for v in values])
            if times is not None:
                point.time_from_start = self.clock.duration(self.clock.steps(times[i]))
            msg.points.append(point)
        self.pub_goal.publish(msg)

    def set_feed_override(self, fraction: float) -> None:
        """Feed override, a fraction 0..1 of the planned feed (the node refuses others)."""
        self.pub_override.publish(Float64(data=float(fraction)))

    def call(self, service: str, request=None, timeout: float = 30.0):
        """Call a std_srvs Trigger (request None) or SetBool (request bool) service;
        returns (success, message)."""
        kind = Trigger if request is None else SetBool
        client = self._services.get(service) or self._services.setdefault(
            service, self.node.create_client(kind, service))
        if not client.wait_for_service(timeout_sec=timeout):
            raise Timeout(f'service {service} is not available')
        future = client.call_async(Trigger.Request() if request is None else SetBool.Request(data=bool(request)))
        self.wait(future.done, f'the answer of {service}', timeout)
        answer = future.result()
        return answer.success, answer.message
