"""The graph's real-time factor while it runs the helix ([5/8]): simulated time on hw_sim's
/clock per wall second, read by an outside subscriber, during `machine-ctrl send helix` to
`machine-ctrl bringup` (a process per node) and `bringup --single-process`; beside it, in
the same run, the bare rclpy ring of 3 hops (bench/ros_chain.py, a process per node, as
many hops as the graph's critical path) as a real-time factor at the machine's period.

    .venv/bin/python bench/helix_rtf.py [--runs 3] [--modes multi,single]

The factor is taken over the send command's whole run (planning in the trajectory node
included: the graph keeps stepping meanwhile) and, as "moving", from the trajectory node's
status 'running' to its next state. The probe reads only /clock (every 10th step) and the
status, so it takes little of the CPU the graph runs on.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from ros_chain import bare_chain_rate, init_context

from machine_ctrl import contract
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.model.config import load_machine

TOOL = str(Path(sys.executable).with_name('machine-ctrl'))


def helix_rtf(single_process: bool) -> tuple[float, float, float]:
    """(factor over the whole send, factor while the trajectory node says 'running', wall
    s of the send)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from rosgraph_msgs.msg import Clock

    from machine_ctrl.ros.messages import qos

    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=5.0) as sup:
        sup.start('bringup', [TOOL, 'bringup'] + (['--single-process'] if single_process else []))
        sup.wait_for_line('bringup', 'all nodes ready after', timeout=300)
        context = init_context(lease.domain_id)
        try:
            node = rclpy.create_node('rtf_probe', context=context)
            clocks = []             # (wall s, sim s): hw_sim's /clock comes every 10 steps
            states = []             # (wall s, /trajectory/status message)
            node.create_subscription(Clock, contract.CLOCK.name, lambda m: clocks.append(
                (time.monotonic(), m.clock.sec + 1e-9 * m.clock.nanosec)), qos(contract.CLOCK_READER_QOS))
            node.create_subscription(DiagnosticStatus, contract.TRAJECTORY_STATUS.name,
                                     lambda m: states.append((time.monotonic(), m.message)),
                                     qos(contract.LATCHED_READER_QOS))
            executor = rclpy.executors.SingleThreadedExecutor(context=context)
            executor.add_node(node)
            sup.start('send', [TOOL, 'send', 'helix'])
            start = time.monotonic()
            while sup['send'].running():
                executor.spin_once(timeout_sec=0.05)
            end = time.monotonic()
            if sup['send'].returncode != 0:
                raise SystemExit(f'send helix failed ({sup["send"].returncode}):\n' + '\n'.join(sup['send'].tail()))
            executor.shutdown()
            node.destroy_node()
        finally:
            context.try_shutdown()
    running = next((t for t, state in states if state == 'running'), None)
    stopped = next((t for t, state in states if running is not None and t > running and state != 'running'), None)
    moving = factor(clocks, running, stopped) if stopped is not None else float('nan')
    return factor(clocks, start, end), moving, end - start


def factor(clocks, start: float, end: float) -> float:
    """Simulated s per wall s between the first and the last /clock inside [start, end]."""
    inside = [c for c in clocks if start <= c[0] <= end]
    return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--modes', default='multi,single')
    args = parser.parse_args(argv)
    period = contract.StepClock.of(load_machine('micromill_9axis')).period_ns * 1e-9
    results = {mode: [] for mode in args.modes.split(',')}
    rings = []
    for run in range(args.runs):
        for mode in results:
            whole, moving, wall = helix_rtf(mode == 'single')
            results[mode].append((whole, moving))
            print(f'run {run + 1} {mode}: factor {whole:.3f} over the send ({wall:.1f} s wall), {moving:.3f} moving',
                  flush=True)
        ring = bare_chain_rate(3, multiprocess=True, executor='events') * period
        rings.append(ring)
        print(f'run {run + 1} bare 3-hop ring (a process per node): factor {ring:.3f}', flush=True)
    print(f'\nmedians of {args.runs} runs (micromill_9axis, period {period * 1e6:g} µs):')
    for mode, values in results.items():
        print(f'  {mode}: {statistics.median(v[0] for v in values):.3f} over the send, '
              f'{statistics.median(v[1] for v in values):.3f} moving')
    print(f'  bare 3-hop ring: {statistics.median(rings):.3f}')


if __name__ == '__main__':
    main()
