"""Lock-step rates ([2/7]): the offline runner against real time, and the node graph
(hw_sim, servo_coarse, servo_fine, dual_stage, reference; circle reference) in separate
processes and in one process, each beside bare rclpy lock-step rings (bench/ros_chain.py,
EventsExecutor like our nodes) measured in the same run, with two hop counts:

* 3 hops, the graph's critical path (hw_sim -> dual_stage -> servo_fine -> hw_sim): what
  bounds a step when the nodes run in parallel, i.e. a process per node;
* 6 hops, every message delivery of a step (the state to servo_coarse, servo_fine and
  dual_stage, the offsets to servo_fine, the two commands to hw_sim): what a step costs
  when one thread does everything, i.e. all nodes in one process (the ring also publishes
  6 times where the graph publishes 4).

    .venv/bin/python bench/graph_rate.py [--seconds 6] [--repeats 3]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

from ros_chain import bare_chain_rate, init_context

from machine_ctrl.model.config import load_machine
from machine_ctrl.ros.graph import default_graph
from hw_sim.offline import run
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from trajectory.contours import circle

CRITICAL_PATH_HOPS = 3
DELIVERIES_PER_STEP = 6


def offline_rate(machine, steps: int = 30000) -> float:
    reference, _ = circle(machine)
    start = time.perf_counter()
    run(machine, reference, steps=steps)
    return steps / (time.perf_counter() - start)


def graph_rate(machine, single_process: bool, seconds: float) -> float:
    """Steps per second read off hw_sim's /clock (every 10 steps) over `seconds` s after a
    warm-up of 2 s once stepping has begun."""
    import rclpy
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock

    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=3.0) as sup:
        if single_process:
            sup.start('graph', [sys.executable, '-m', 'machine_ctrl.ros.graph', '--machine', str(machine.yaml_path)])
        else:
            sup.start_nodes(default_graph(machine))
        context = init_context(lease.domain_id)
        try:
            node = Node('rate_probe', context=context)
            last = {}
            node.create_subscription(Clock, '/clock', lambda m: last.update(
                step=(m.clock.sec * 1_000_000_000 + m.clock.nanosec) // 100_000, t=time.monotonic()), 10)
            executor = rclpy.executors.SingleThreadedExecutor(context=context)
            executor.add_node(node)

            def spin_until(predicate, timeout):
                deadline = time.monotonic() + timeout
                while not predicate() and time.monotonic() < deadline:
                    executor.spin_once(timeout_sec=0.05)
                    sup.check()
            spin_until(lambda: last.get('step', 0) > 100, 60)
            spin_until(lambda: False, 2.0)
            step0, t0 = last['step'], last['t']
            spin_until(lambda: False, seconds)
            rate = (last['step'] - step0) / (last['t'] - t0)
            executor.shutdown()
            node.destroy_node()
        finally:
            context.try_shutdown()
    return rate


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=6.0)
    parser.add_argument('--repeats', type=int, default=3, help='interleaved measurements per mode')
    args = parser.parse_args(argv)
    machine = load_machine()
    real_time = 1.0 / machine.control_period
    rate = offline_rate(machine)
    print(f'offline runner, {machine.name} circle, dual stage: {rate:8.0f} steps/s = {rate / real_time:.2f}x real time '
          f'({real_time:.0f} steps/s)')
    hops = (CRITICAL_PATH_HOPS, DELIVERIES_PER_STEP)
    print(f'graph (median of {args.repeats})'.ljust(22) + 'ours steps/s'.rjust(13)
          + ''.join(f'{f"ring {h} hops":>13s}{"ratio":>7s}' for h in hops) + '  ratios of the runs (3 hops; 6 hops)')
    for single in (False, True):
        runs = []
        for _ in range(args.repeats):         # interleaved: all see the same machine load
            ours = graph_rate(machine, single, args.seconds)
            runs.append([ours] + [bare_chain_rate(h, multiprocess=not single, executor='events') for h in hops])
        medians = [statistics.median(run[i] for run in runs) for i in range(3)]
        pairs = '; '.join(' '.join(f'{run[0] / run[i]:.2f}' for run in runs) for i in (1, 2))
        label = 'one process' if single else 'one process per node'
        print(label.ljust(22) + f'{medians[0]:13.0f}'
              + ''.join(f'{medians[i]:13.0f}{medians[0] / medians[i]:7.2f}' for i in (1, 2)) + f'  {pairs}', flush=True)


if __name__ == '__main__':
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    main()
