"""The caller's side of the trajectory node's command API (README "Node graph"): send tool
paths and joint goals, call the services, follow /trajectory/status and the goal status.
What another robot or program does, packaged for `machine-ctrl send` / `move`, the demo and
the graph tests. Spins its own node in a background thread.

Readiness: hw_sim publishes contract.READY (latched) once the graph has completed its first
step; :meth:`MachineClient.wait_ready` waits for it with a timeout and a clear message.

Losses: the goal status is read with the writer's liveliness lease (contract.GOAL_STATUS_QOS),
so :attr:`MachineClient.trajectory_lost` says within the lease that the trajectory node is
gone or stopped; hw_sim's loss the trajectory node reports itself (the goal aborted).

Goals: a goal sent with a stamp (:meth:`MachineClient.stamp_now`: the wall clock, unique per
request) is found in the latched goal status (action_msgs/GoalStatusArray) by that stamp —
GoalInfo.stamp is the request's header.stamp — which gives its id (:meth:`goal_of`); its
states and, from the trajectory node's /diagnostics goal entries, the reason it was aborted
or canceled and its label are kept by id (:attr:`goal_states`, :attr:`goal_entries`).
"""
from __future__ import annotations

import threading
import time
import uuid

from action_msgs.msg import GoalStatusArray
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from nav_msgs.msg import Path
from std_msgs.msg import Float64

from machine_ctrl import contract
from machine_ctrl.ros import messages as ros_io
from machine_ctrl.ros.node_common import watch_liveliness
from machine_ctrl.model.config import MachineConfig

READY_TIMEOUT = 30.0            # s (wall) a command-line client waits for the graph
NOT_READY = 'the graph is not ready after {timeout:g} s: is it up? machine-ctrl bringup'
# action_msgs/GoalStatus codes -> the names the trajectory node gives them (trajectory.goals)
GOAL_STATES = {0: 'unknown', 1: 'accepted', 2: 'executing', 3: 'canceling', 4: 'succeeded', 5: 'canceled',
               6: 'aborted'}
TERMINAL = ('succeeded', 'canceled', 'aborted')


class Timeout(RuntimeError):
    pass


class MachineClient:
    def __init__(self, node, machine: MachineConfig):
        self.node, self.machine = node, machine
        self.clock = ros_io.StepClock.of(machine)
        self.statuses: list[DiagnosticStatus] = []
        self.ready: bool | None = None                     # None: nothing heard from hw_sim yet
        self.goal_ids: dict[tuple[int, int], str] = {}     # request stamp -> goal id (uuid text)
        self.goal_states: dict[str, list[str]] = {}        # goal id -> states seen, in order
        self.goal_entries: dict[str, dict] = {}            # goal id -> its newest /diagnostics values
        # the names of the /diagnostics statuses heard: a node's name here means this client's
        # reader is matched with that node's writer (a goal entry it publishes from now on
        # arrives; /diagnostics is volatile, so one published before is lost to a new client)
        self.diagnostics_heard: set[str] = set()
        node.create_subscription(DiagnosticStatus, contract.TRAJECTORY_STATUS.name, self.statuses.append,
                                 ros_io.qos(contract.LATCHED_READER_QOS))
        node.create_subscription(Bool, contract.READY.name, self._on_ready, ros_io.qos(contract.READY.qos))
        # asks for the goal status writer's liveliness: the trajectory node lost (killed,
        # stopped, hung) is known within the lease (README "Faults")
        self.trajectory_alive: bool | None = None          # None: not heard of yet
        watch_liveliness(node, GoalStatusArray, contract.GOAL_STATUS.name, contract.GOAL_STATUS_READER_QOS,
                         self._on_trajectory_alive, self._on_goals)
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_diagnostics,
                                 ros_io.qos(contract.DIAGNOSTICS_READER_QOS))
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

    # -- subscriptions (the spin thread) ---------------------------------------------------
    def _on_ready(self, msg: Bool) -> None:
        self.ready = bool(msg.data)

    def _on_trajectory_alive(self, alive: bool) -> None:
        self.trajectory_alive = alive

    @property
    def trajectory_lost(self) -> str | None:
        """Why the trajectory node is taken for lost (it was alive, its liveliness lease ran
        out), or None."""
        if self.trajectory_alive is False:
            return (f'the trajectory node (no sign of life within the {contract.LIVELINESS_LEASE:g} s liveliness '
                    f'lease of {contract.GOAL_STATUS.name}: killed, stopped or hung)')
        return None

    def _on_goals(self, msg: GoalStatusArray) -> None:
        for status in msg.status_list:
            info = status.goal_info
            goal_id = str(uuid.UUID(bytes=bytes(info.goal_id.uuid)))
            self.goal_ids.setdefault((info.stamp.sec, info.stamp.nanosec), goal_id)
            seen = self.goal_states.setdefault(goal_id, [])
            state = GOAL_STATES.get(status.status, str(status.status))
            if not seen or seen[-1] != state:
                seen.append(state)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diagnostics_heard.add(status.name)
            values = {kv.key: kv.value for kv in status.values}
            if 'goal_id' in values and 'status_code' in values:
                self.goal_entries[values['goal_id']] = values

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

    def wait_ready(self, timeout: float = READY_TIMEOUT, check=None) -> None:
        """Wait until hw_sim says the graph is ready (contract.READY, latched); Timeout with
        a message that says what to do."""
        try:
            self.wait(lambda: self.ready, 'the graph', timeout, check)
        except Timeout:
            raise Timeout(NOT_READY.format(timeout=timeout)) from None

    def listens(self, publisher) -> bool:
        """Whether the trajectory node of this client's namespace subscribes `publisher`'s
        topic and every subscriber of the topic is matched with it (a message published now
        reaches the trajectory node)."""
        infos = self.node.get_subscriptions_info_by_topic(publisher.topic_name)
        namespace = self.node.get_namespace()
        return (any(info.node_name == 'trajectory' and info.node_namespace == namespace for info in infos)
                and publisher.get_subscription_count() >= len(infos))

    @property
    def command_publishers(self) -> tuple:
        """The trajectory node's command topics this client publishes: path, joint goal, feed override."""
        return self.pub_path, self.pub_goal, self.pub_override

    def wait_listening(self, timeout: float = READY_TIMEOUT, check=None, publishers=None) -> None:
        """Wait until the trajectory node listens to `publishers` (default: this client's tool
        path and joint goal) and its status has come: the command topics are volatile, so a
        command published before the match is lost (a loaded run lost a test's first path so)."""
        publishers = (self.pub_path, self.pub_goal) if publishers is None else publishers
        self.wait(lambda: self.statuses and all(self.listens(p) for p in publishers),
                  'the trajectory node (is the graph up? machine-ctrl bringup)', timeout, check)

    def states_seen(self, after: int, states) -> bool:
        """The statuses after the first `after` went through `states` in this order."""
        wanted = list(states)
        for status in self.statuses[after:]:
            if wanted and status.message == wanted[0]:
                wanted.pop(0)
        return not wanted

    def wait_states(self, after: int, states, timeout: float = 120.0, check=None) -> None:
        self.wait(lambda: self.states_seen(after, states), f'states {list(states)}', timeout, check)

    # -- goals -----------------------------------------------------------------------------
    @staticmethod
    def stamp_now() -> Time:
        """A request stamp: the wall clock (unique per request, so it names the goal)."""
        sec, nanosec = contract.split_ns(time.time_ns())
        return Time(sec=sec, nanosec=nanosec)

    def goal_of(self, stamp: Time) -> str | None:
        """The id of the goal sent with `stamp`, once the goal status has it."""
        return self.goal_ids.get((stamp.sec, stamp.nanosec))

    def goal_state(self, goal_id: str) -> str:
        """The goal's newest state ('' before any)."""
        seen = self.goal_states.get(goal_id)
        return seen[-1] if seen else ''

    # -- commands --------------------------------------------------------------------------
    def send_path(self, cl, frame: str | None = None, stamp: Time | None = None) -> Time:
        """A tool path; returns the request's stamp (`stamp`, default now)."""
        msg = ros_io.path_message(cl, frame or self.machine.workpiece_frame)
        msg.header.stamp = stamp or self.stamp_now()
        self.pub_path.publish(msg)
        return msg.header.stamp

    def send_goal(self, names, points, times=None, stamp: Time | None = None) -> Time:
        """Joint goal: `points` hold values for `names`; `times` (s) earliest arrivals.
        Returns the request's stamp (`stamp`, default now)."""
        msg = JointTrajectory()
        msg.header.stamp = stamp or self.stamp_now()
        msg.joint_names = list(names)
        for i, values in enumerate(points):
            point = JointTrajectoryPoint(positions=[float(v) for v in values])
            if times is not None:
                point.time_from_start = self.clock.duration(self.clock.steps(times[i]))
            msg.points.append(point)
        self.pub_goal.publish(msg)
        return msg.header.stamp

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

    def set_parameters(self, node: str, values: dict, timeout: float = 30.0) -> list[str]:
        """Set parameters of `node` (relative name, rcl_interfaces/SetParameters, what
        `ros2 param set` calls); returns the reasons of those refused (empty: all taken)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        service = f'{node}/set_parameters'
        client = self._services.get(service) or self._services.setdefault(
            service, self.node.create_client(SetParameters, service))
        if not client.wait_for_service(timeout_sec=timeout):
            raise Timeout(f'service {service} is not available')
        request = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        future = client.call_async(request)
        self.wait(future.done, f'the answer of {service}', timeout)
        return [f'{name}: {r.reason}' for name, r in zip(values, future.result().results) if not r.successful]

    def get_parameters(self, node: str, names, timeout: float = 30.0) -> dict:
        """Values of parameters of `node` (rcl_interfaces/GetParameters, what `ros2 param get`
        calls), by name."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        service = f'{node}/get_parameters'
        client = self._services.get(service) or self._services.setdefault(
            service, self.node.create_client(GetParameters, service))
        if not client.wait_for_service(timeout_sec=timeout):
            raise Timeout(f'service {service} is not available')
        future = client.call_async(GetParameters.Request(names=list(names)))
        self.wait(future.done, f'the answer of {service}', timeout)
        return {name: parameter_value_to_python(value) for name, value in zip(names, future.result().values)}

    def cancel(self, goal_id: str | None = None, timeout: float = 30.0):
        """action_msgs/CancelGoal on the trajectory node (`goal_id` None: the active goal);
        returns (return code, ids of the goals now canceling)."""
        from action_msgs.srv import CancelGoal
        client = self._services.get(contract.CANCEL.name) or self._services.setdefault(
            contract.CANCEL.name, self.node.create_client(CancelGoal, contract.CANCEL.name))
        if not client.wait_for_service(timeout_sec=timeout):
            raise Timeout(f'service {contract.CANCEL.name} is not available')
        request = CancelGoal.Request()
        if goal_id is not None:
            request.goal_info.goal_id.uuid = list(uuid.UUID(goal_id).bytes)
        future = client.call_async(request)
        self.wait(future.done, f'the answer of {contract.CANCEL.name}', timeout)
        answer = future.result()
        return answer.return_code, [str(uuid.UUID(bytes=bytes(g.goal_id.uuid))) for g in answer.goals_canceling]
