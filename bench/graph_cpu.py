"""One CPU per graph: the lock-step graph (the default micromill graph with the trajectory
node, stepping idle: hw_sim, servo_coarse, servo_fine, dual_stage, trajectory; a process
per node) with its processes free to run on every CPU and with all of them on one CPU,
interleaved; for each, the steps per second (hw_sim's /clock) and the CPU its processes
used per step (utime + stime from /proc), beside the bare 3-hop rclpy ring
(bench/ros_chain.py, EventsExecutor, a process per hop) under the same two affinities.

    .venv/bin/python bench/graph_cpu.py [--seconds 15] [--repeats 2]

Why: a node that publishes wakes the next node's thread; on another CPU that is a
cross-CPU wake-up, which in a VM (this project's machines are 2-vCPU VMs) costs far more
than on bare metal. The probe (this process) takes the affinity of the row too; it reads
only /clock, every 10th step. Not used by the test suite (bench/RESULTS.md "One CPU per
graph": the trajectory node's planner, niced, then starves beside its graph).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import time

from ros_chain import bare_chain_rate, init_context
from view_cost import _cpu_seconds as cpu_seconds

from machine_ctrl import contract
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.model.config import load_machine
from machine_ctrl.ros.graph import default_graph

@contextlib.contextmanager
def affinity(cpus: set[int]):
    """This process (and what it starts meanwhile) on `cpus`."""
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, cpus)
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def graph_cpu(machine, seconds: float) -> tuple[float, dict[str, float]]:
    """(steps per second, {node: CPU us per step}) over `seconds` s, 2 s after stepping began."""
    import rclpy
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    from machine_ctrl.ros.messages import qos
    period_ns = round(machine.control_period * 1e9)
    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=3.0) as sup:
        sup.start_nodes(default_graph(machine, contour=None))
        context = init_context(lease.domain_id)
        try:
            node = Node('cpu_probe', context=context)
            last = {}
            node.create_subscription(Clock, contract.CLOCK.name, lambda m: last.update(
                step=(m.clock.sec * 1_000_000_000 + m.clock.nanosec) // period_ns, t=time.monotonic()),
                qos(contract.CLOCK_READER_QOS))
            executor = rclpy.executors.SingleThreadedExecutor(context=context)
            executor.add_node(node)

            def spin_for(seconds, predicate=lambda: False):
                deadline = time.monotonic() + seconds
                while not predicate() and time.monotonic() < deadline:
                    executor.spin_once(timeout_sec=0.05)
                    sup.check()
            spin_for(120, lambda: last.get('step', 0) > 100)
            spin_for(2.0)
            names = sup.alive()
            cpu0 = {name: cpu_seconds(sup[name].pid) for name in names}
            step0, t0 = last['step'], last['t']
            spin_for(seconds)
            steps = last['step'] - step0
            rate = steps / (last['t'] - t0)
            cpu = {name: (cpu_seconds(sup[name].pid) - cpu0[name]) / steps * 1e6 for name in names}
            executor.shutdown()
            node.destroy_node()
        finally:
            context.try_shutdown()
    return rate, cpu


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=15.0)
    parser.add_argument('--repeats', type=int, default=2, help='interleaved measurements per layout')
    args = parser.parse_args(argv)
    machine = load_machine()
    allowed = sorted(os.sched_getaffinity(0))
    layouts = {f'every CPU ({len(allowed)})': set(allowed), f'one CPU ({allowed[0]})': {allowed[0]}}
    rows = {label: [] for label in layouts}
    for _ in range(args.repeats):               # interleaved: both see the same machine load
        for label, cpus in layouts.items():
            with affinity(cpus):
                rate, cpu = graph_cpu(machine, args.seconds)
                ring = bare_chain_rate(3, multiprocess=True, executor='events')
            rows[label].append((rate, cpu, ring))
    print(f'{machine.name}, trajectory node idle, a process per node; {args.repeats} x {args.seconds:g} s, '
          f'medians; {os.cpu_count()} CPUs')
    names = list(rows[next(iter(rows))][0][1])
    print('layout'.ljust(18) + 'steps/s'.rjust(9) + 'CPU us/step'.rjust(13)
          + ''.join(n[:12].rjust(13) for n in names) + 'ring 3 hops'.rjust(13) + '  runs (steps/s; ring)')
    for label, runs in rows.items():
        rate = statistics.median(r[0] for r in runs)
        per_node = {n: statistics.median(r[1][n] for r in runs) for n in names}
        ring = statistics.median(r[2] for r in runs)
        print(label.ljust(18) + f'{rate:9.0f}{sum(per_node.values()):13.0f}'
              + ''.join(f'{per_node[n]:13.0f}' for n in names) + f'{ring:13.0f}'
              + '  ' + ' '.join(f'{r[0]:.0f}' for r in runs) + '; ' + ' '.join(f'{r[2]:.0f}' for r in runs), flush=True)


if __name__ == '__main__':
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    main()
