"""The graph's real-time factor while it runs the helix ([5/8]): simulated time on hw_sim's
/clock per wall second, read by an outside subscriber, during `machine-ctrl send helix` to
`machine-ctrl bringup` (a process per node) and `bringup --single-process`; beside it, in
the same run, the bare rclpy ring of 3 hops (bench/ros_chain.py, a process per node, as
many hops as the graph's critical path) as a real-time factor at the machine's period.

    .venv/bin/python bench/helix_rtf.py [--runs 3] [--modes multi,single]

The factor is taken over the send command's whole run (planning in the trajectory node
included: the graph keeps stepping meanwhile) and, as "moving", over the wall seconds in
which the machine's first axis moved by more than 1 µm.
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
    """(factor over the whole send, factor while moving, wall s of the send)."""
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=5.0) as sup:
        sup.start('bringup', [TOOL, 'bringup'] + (['--single-process'] if single_process else []))
        sup.wait_for_line('bringup', 'all nodes ready after', timeout=300)
        context = init_context(lease.domain_id)
        try:
            node = rclpy.create_node('rtf_probe', context=context)
            samples = []            # (wall s, sim s, first axis position)
            position = [None]
            best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
            node.create_subscription(JointState, contract.JOINT_STATES.name,
                                     lambda m: position.__setitem__(0, m.position[0] if m.position else None),
                                     best_effort)
            node.create_subscription(Clock, contract.CLOCK.name, lambda m: samples.append(
                (time.monotonic(), m.clock.sec + 1e-9 * m.clock.nanosec, position[0])), best_effort)
            executor = rclpy.executors.SingleThreadedExecutor(context=context)
            executor.add_node(node)
            sup.start('send', [TOOL, 'send', 'helix'])
            start = time.monotonic()
            while sup['send'].running():
                executor.spin_once(timeout_sec=0.05)
            wall = time.monotonic() - start
            if sup['send'].returncode != 0:
                raise SystemExit(f'send helix failed ({sup["send"].returncode}):\n' + '\n'.join(sup['send'].tail()))
            executor.shutdown()
            node.destroy_node()
        finally:
            context.try_shutdown()
    inside = [s for s in samples if s[0] >= start]
    whole = (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])
    moving_sim = moving_wall = 0.0
    for (t0, s0, p0), (t1, s1, p1) in zip(inside, inside[1:]):
        if p0 is not None and p1 is not None and abs(p1 - p0) > 1e-6:
            moving_sim, moving_wall = moving_sim + s1 - s0, moving_wall + t1 - t0
    return whole, (moving_sim / moving_wall if moving_wall else float('nan')), wall


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
