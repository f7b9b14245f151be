"""Baseline for the lock-step graph benchmarks: a bare rclpy publish/subscribe ring.

H nodes in a ring, H hops per step: node 0 publishes step k on /chain/hop0, node i
republishes what it receives on /chain/hop{i}, and node 0 publishes step k+1 only after
step k has come back from node H-1. That is the shape of our lock-step graph (hw_sim ->
servo -> hw_sim is H = 2; hw_sim -> servo -> fine servo -> hw_sim is H = 3), with the
message it sends (sensor_msgs/JointState, 9 joints, positions/velocities/efforts, stamp),
reliable QoS, depth 10, and nothing else: no conversion, no computation. Whatever our graph
adds on top of this rate is ours.

    .venv/bin/python bench/ros_chain.py [--steps N] [--repeats R] [--hops 2 3]

Importable: ``bare_chain_rate(hops, steps, multiprocess, executor)`` returns steps per
second, so another benchmark can print its rate beside the bare one measured in the same
run. Each call leases its own ROS domain id (machine_ctrl.app.processes) and keeps discovery
on localhost, so it disturbs neither a test session nor another benchmark.

The relays of the multi-process ring are this module run as
``python -m ros_chain relay --ros-args -r __node:=chain_relay_I -p index:=I -p hops:=H
-p executor:=E`` with bench/ on PYTHONPATH.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState

from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.ros.node_common import bounded_teardown

BENCH_DIR = Path(__file__).resolve().parent
EXECUTORS = ('single', 'events')
JOINTS = ['x_c', 'y_c', 'z_c', 'x_f', 'y_f', 'z_f', 'a_f', 'b_f', 'c_f']
STEP_NS = 100_000            # stamp of step k = k control periods of 100 us (10 kHz)
QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
MATCH_TIMEOUT = 30.0         # s for discovery (child start-up included) before giving up


def topic(index: int, hops: int) -> str:
    """The topic node ``index`` publishes on; node index+1 (mod hops) subscribes to it."""
    return f'/chain/hop{index % hops}'


def make_executor(kind: str, context: Context):
    """'single': rclpy.executors.SingleThreadedExecutor; 'events': the experimental
    EventsExecutor (callbacks dispatched from C++ on middleware events)."""
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    if kind == 'events':
        return EventsExecutor(context=context)
    raise ValueError(f'executor must be one of {EXECUTORS}, not {kind!r}')


def joint_state() -> JointState:
    """The message our graph sends each step: 9 joints, all three arrays filled."""
    msg = JointState()
    msg.name = list(JOINTS)
    msg.position = [0.001 * i for i in range(len(JOINTS))]
    msg.velocity = [0.01 * i for i in range(len(JOINTS))]
    msg.effort = [0.1 * i for i in range(len(JOINTS))]
    return msg


def set_step(msg: JointState, k: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * STEP_NS, 1_000_000_000)


def step_of(msg: JointState) -> int:
    return (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec) // STEP_NS


class Relay:
    """Node i of the ring: republishes every message from hop i-1 on hop i, unchanged (the
    received object itself, so the only cost is the middleware's)."""

    def __init__(self, node: Node, index: int, hops: int):
        self.node = node
        self.pub = node.create_publisher(JointState, topic(index, hops), QOS)
        self.sub = node.create_subscription(JointState, topic(index - 1, hops), self.pub.publish, QOS)

    def matched(self) -> bool:
        """Both of its endpoints have matched their peer at the DDS level (the graph cache
        alone can list an endpoint before a reliable message to it would arrive)."""
        return self.pub.get_subscription_count() >= 1 and self.sub.get_publisher_count() >= 1


class Head(Relay):
    """Node 0: sends step k+1 when step k has come back, from the subscription callback
    itself, so a step costs exactly one trip round the ring."""

    def __init__(self, node: Node, hops: int):
        self.node = node
        self.msg = joint_state()
        self.sent = 0
        self.target = 0
        self.future = None
        self.pub = node.create_publisher(JointState, topic(0, hops), QOS)
        self.sub = node.create_subscription(JointState, topic(-1, hops), self._returned, QOS)

    def _send(self, k: int) -> None:
        set_step(self.msg, k)
        self.pub.publish(self.msg)
        self.sent = k

    def _returned(self, msg: JointState) -> None:
        k = step_of(msg)
        if k != self.sent:        # lock step: nothing else can be in flight
            self.future.set_exception(RuntimeError(f'step {k} came back while {self.sent} was in flight'))
        elif k >= self.target:
            self.future.set_result(k)
        else:
            self._send(k + 1)

    def run(self, executor, steps: int, timeout: float) -> float:
        """Go round the ring ``steps`` times; returns the elapsed wall time in s."""
        self.future = Future()
        self.target = self.sent + steps
        start = time.perf_counter()
        self._send(self.sent + 1)
        executor.spin_until_future_complete(self.future, timeout_sec=timeout)
        elapsed = time.perf_counter() - start
        if not self.future.done():
            raise TimeoutError(f'ring stalled: step {self.sent} sent, not back after {timeout} s')
        self.future.result()
        return elapsed


class PacedHead(Head):
    """Node 0 paced by the wall clock instead: a timer sends step k+1 every `period` s whether
    or not step k came back, and the time until each step comes back is kept, a step not
    back at the next tick counted as missed with what it had waited (hw_sim's paced mode
    measures its graph the same way: hw_sim/pacing.py)."""

    def run_paced(self, executor, period: float, seconds: float):
        """Pace the ring for `seconds`; returns (LatencyHistogram of the round trips, missed, ticks)."""
        from rclpy.clock import Clock, ClockType

        from hw_sim.pacing import LatencyHistogram
        self.latency, self.missed, self.ticks, self.back = LatencyHistogram(), 0, 0, True

        def tick() -> None:
            now = time.monotonic()
            if not self.back:
                self.missed += 1
                self.latency.add(now - self.sent_at)
            self.back, self.sent_at = False, now
            self.ticks += 1
            self._send(self.sent + 1)
        timer = self.node.create_timer(period, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
        executor.spin_until_future_complete(Future(), timeout_sec=seconds)
        self.node.destroy_timer(timer)
        return self.latency, self.missed, self.ticks

    def _returned(self, msg: JointState) -> None:
        if not self.back and step_of(msg) == self.sent:
            self.back = True
            self.latency.add(time.monotonic() - self.sent_at)


def init_context(domain_id: int, args=None) -> Context:
    """A private context in ``domain_id`` with localhost-only discovery. rcl reads
    ROS_AUTOMATIC_DISCOVERY_RANGE when the context is initialised and rclpy cannot pass it
    otherwise, so it is set just for that call and then restored."""
    context = Context()
    saved = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    try:
        rclpy.init(args=args, context=context, domain_id=domain_id)
    finally:
        if saved is None:
            del os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']
        else:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = saved
    return context


def wait_until(predicate, timeout: float, what: str, poll=None) -> None:
    """Matching happens on DDS threads: no spinning needed, just polling."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if poll is not None:
            poll()
        if time.monotonic() > deadline:
            raise TimeoutError(f'{what} not within {timeout} s')
        time.sleep(0.01)


class Chain:
    """A ring set up once (nodes, executor, children, discovery) and measured repeatedly.

    ``multiprocess``: node 0 in this process, each relay in a child process of its own;
    otherwise all H nodes in this process on one executor. Every process uses the
    executor kind ``executor``.
    """

    def __init__(self, hops: int, multiprocess: bool, executor: str = 'single', head=Head):
        if hops < 2:
            raise ValueError('a ring needs at least 2 hops')
        if executor not in EXECUTORS:
            raise ValueError(f'executor must be one of {EXECUTORS}, not {executor!r}')
        self.hops, self.multiprocess, self.executor_kind, self.head_class = hops, multiprocess, executor, head
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> Chain:
        try:
            self._start()
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc_info) -> None:
        self._stack.close()

    def _start(self) -> None:
        # Callbacks pop in reverse: executor down, nodes destroyed, context shut down,
        # children stopped, domain released.
        lease = self._stack.enter_context(reserve_ros_domain())
        self.supervisor = self._stack.enter_context(Supervisor(self._child_env(lease.domain_id), stop_timeout=3.0))
        self.context = init_context(lease.domain_id)
        self._stack.callback(self.context.try_shutdown)
        ring = [self.head_class(self._node('chain_head'), self.hops)]
        if self.multiprocess:
            for i in range(1, self.hops):
                self.supervisor.start(f'chain_relay_{i}', self._relay_argv(i))
        else:
            ring += [Relay(self._node(f'chain_relay_{i}'), i, self.hops) for i in range(1, self.hops)]
        self.head = ring[0]
        self.executor = make_executor(self.executor_kind, self.context)
        self._stack.callback(self.executor.shutdown)
        for member in ring:
            self.executor.add_node(member.node)
        wait_until(lambda: all(member.matched() for member in ring), MATCH_TIMEOUT,
                   'publishers and subscriptions of this process matched', poll=self.supervisor.check)
        for name in self.supervisor.children:        # a relay that died raises ChildExited here
            self.supervisor.wait_for_line(name, 'ready', MATCH_TIMEOUT)

    def _node(self, name: str) -> Node:
        node = Node(name, context=self.context)
        self._stack.callback(node.destroy_node)
        return node

    @staticmethod
    def _child_env(domain_id: int) -> dict:
        env = isolated_ros_env(domain_id)
        env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(BENCH_DIR), env.get('PYTHONPATH')]))
        return env

    def _relay_argv(self, index: int) -> list[str]:
        return [sys.executable, '-m', 'ros_chain', 'relay', '--ros-args', '-r', f'__node:=chain_relay_{index}',
                '-p', f'index:={index}', '-p', f'hops:={self.hops}', '-p', f'executor:={self.executor_kind}']

    def measure(self, steps: int) -> float:
        """Steps (round trips) per second over ``steps`` consecutive steps."""
        try:
            elapsed = self.head.run(self.executor, steps, timeout=10.0 + 0.01 * steps)
        except TimeoutError:
            self.supervisor.check()       # a dead relay is the better explanation
            raise
        return steps / elapsed


def bare_chain_rate(hops: int, steps: int = 2000, multiprocess: bool = False, executor: str = 'single',
                    warmup: int = 200) -> float:
    """Steps per second of the bare lock-step ring (see module docstring), measured over
    ``steps`` steps after discovery has matched every endpoint and ``warmup`` steps
    (first-message allocations, caches, DDS flow state) have run. Set-up is not timed;
    it takes about a second per child process."""
    with Chain(hops, multiprocess, executor) as chain:
        chain.measure(warmup)
        return chain.measure(steps)


def spin_forever(executor, context: Context) -> None:
    """executor.spin(), except that the EventsExecutor of this rclpy (7.1.6 wheels) must be
    given a finite timeout: with none (spin(), spin_once(), spin_until_future_complete
    without timeout_sec) a node that only receives from other processes never gets a
    callback, and SIGINT/SIGTERM do not end it, only SIGKILL does (seen here, cause not
    traced; any finite timeout works)."""
    if not isinstance(executor, SingleThreadedExecutor):
        never = Future()
        while context.ok():
            executor.spin_until_future_complete(never, timeout_sec=3600.0)
    else:
        executor.spin()


def relay_main(argv: list[str]) -> int:
    """A relay as its own process: parameters index, hops, executor. Prints 'ready' once
    both endpoints are matched and exits cleanly on SIGINT (rclpy's handler shuts the
    context down, which ends spin)."""
    rclpy.init(args=argv)
    node = executor = None
    try:
        node = Node('chain_relay')
        index = node.declare_parameter('index', 1).value
        hops = node.declare_parameter('hops', 2).value
        executor = make_executor(node.declare_parameter('executor', 'single').value, node.context)
        relay = Relay(node, index, hops)
        executor.add_node(node)
        wait_until(relay.matched, MATCH_TIMEOUT, f'relay {index} matched')
        print('ready', flush=True)
        spin_forever(executor, node.context)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # a teardown that hangs in rmw (as the nodes' did, run89 / run107; a relay's, run114)
        # prints its native stacks, as every node's does
        with bounded_teardown():
            if executor is not None:
                executor.shutdown()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
    return 0


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, default=2000, help='timed steps per repeat (default 2000)')
    parser.add_argument('--repeats', type=int, default=3, help='timed repeats per configuration (default 3)')
    parser.add_argument('--warmup', type=int, default=200)
    parser.add_argument('--hops', type=int, nargs='+', default=[2, 3])
    parser.add_argument('--max-others', type=float, default=10.0, metavar='PCT',
                        help='measure a row again (up to --tries times) while other processes used more '
                             'than PCT%% of one core during it (default 10)')
    parser.add_argument('--tries', type=int, default=5)
    args = parser.parse_args(argv)
    print(f'bare rclpy lock-step ring, JointState x{len(JOINTS)}, reliable depth 10; rclpy '
          f'{rclpy_version()}, {os.cpu_count()} cores; {args.repeats} x {args.steps} steps after '
          f'{args.warmup} warm-up; median (min-max)')
    print(f'{"H":>2} {"processes":>9} {"executor":>8} {"steps/s":>8} {"(min-max)":>13} {"us/step":>8} '
          f'{"us/hop":>7} {"others":>7}')
    for hops in args.hops:
        for multiprocess in (False, True):
            for kind in EXECUTORS:
                for _ in range(max(args.tries, 1)):
                    rates, others = measure_row(hops, multiprocess, kind, args)
                    if others <= args.max_others:
                        break
                rate = statistics.median(rates)
                print(f'{hops:>2} {hops if multiprocess else 1:>9} {kind:>8} {rate:8.0f} '
                      f'{f"({min(rates):.0f}-{max(rates):.0f})":>13} {1e6 / rate:8.1f} {1e6 / rate / hops:7.1f} '
                      f'{others:6.0f}%{"" if others <= args.max_others else " busy"}', flush=True)
    print('others: CPU used by other processes on this machine while the row was measured, % of one '
          f'core; a row over {args.max_others:g}% was measured again ({args.tries} tries at most; "busy": '
          'never below it, not a fair number)')


def measure_row(hops: int, multiprocess: bool, kind: str, args) -> tuple[list[float], float]:
    """One table row: set up, warm up, ``repeats`` timed runs; with the machine's other load."""
    with OtherLoad() as load:
        with Chain(hops, multiprocess, kind) as chain:
            chain.measure(args.warmup)
            rates = [chain.measure(args.steps) for _ in range(args.repeats)]
    return rates, load.percent


class OtherLoad:
    """CPU time the rest of the machine used while the block ran, as % of one core: the
    whole machine's busy time (/proc/stat) minus this process's and its reaped children's
    (os.times). On a shared 2-core machine a benchmark is only honest with this beside it."""

    percent = float('nan')

    def __enter__(self) -> OtherLoad:
        self._start = (time.monotonic(), _machine_busy_s(), _own_cpu_s())
        return self

    def __exit__(self, *exc_info) -> None:
        wall, busy, own = (end - start for end, start in
                           zip((time.monotonic(), _machine_busy_s(), _own_cpu_s()), self._start))
        self.percent = max(busy - own, 0.0) / wall * 100


def _machine_busy_s() -> float:
    """CPU seconds all cores spent working here since boot (Linux /proc/stat; NaN elsewhere);
    steal (the hypervisor running another guest) is not work done on this machine."""
    try:
        with open('/proc/stat') as f:
            user, nice, system, idle, iowait, irq, softirq = map(int, f.readline().split()[1:8])
    except OSError:
        return float('nan')
    return (user + nice + system + irq + softirq) / os.sysconf('SC_CLK_TCK')


def _own_cpu_s() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def rclpy_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version('ros-jazzy-rclpy')
    except PackageNotFoundError:
        return '?'


if __name__ == '__main__':
    if sys.argv[1:2] == ['relay']:
        sys.exit(relay_main(sys.argv))
    main(sys.argv[1:])
