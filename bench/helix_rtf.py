"""The graph's real-time factor while it runs the helix ([5/8]): simulated time on hw_sim's
/clock per wall second, read by an outside subscriber, during `machine-ctrl send helix` to
`machine-ctrl bringup` (a process per node) and `bringup --single-process`; beside it, in
the same run, the bare rclpy ring of 3 hops (bench/ros_chain.py, a process per node, as
many hops as the graph's critical path) as a real-time factor at the machine's period.

    .venv/bin/python bench/helix_rtf.py [--runs 3] [--modes multi,single,single+record] [--baseline REV]

The factor is taken over the send command's whole run (planning in the trajectory node
included: the graph keeps stepping meanwhile) and, as "moving", from the trajectory node's
status 'running' to its next state. The probe reads only /clock (every 10th step) and the
status, so it takes little of the CPU the graph runs on. `single+record` is
`bringup --single-process --record`: the recorder, in its own process, reads every per-step
stream from outside the graph's process (machine_ctrl/ros/local_bus.py: its writers then
publish to DDS too). `--baseline REV` measures each mode with the nodes of that revision
too (a git worktree, first on PYTHONPATH), alternating with this tree run by run.
"""
from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

from baseline import labelled_trees, tree_env
from ros_chain import bare_chain_rate, init_context

from machine_ctrl import contract
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.model.config import load_machine

TOOL = str(Path(sys.executable).with_name('machine-ctrl'))
# bringup's options per mode: a process per node, all in one, all in one with the recorder
# beside it (its own process: it reads every per-step stream from outside the graph's; the
# bag goes to a temporary directory)
MODES = {'multi': [], 'single': ['--single-process'], 'single+record': ['--single-process', '--record']}


def helix_rtf(mode: str, tree: Path | None = None) -> tuple[float, float, float]:
    """(factor over the whole send, factor while the trajectory node says 'running', wall
    s of the send) of a bringup in `mode` (:data:`MODES`), its nodes from `tree` (default:
    this one)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from rosgraph_msgs.msg import Clock

    from machine_ctrl.ros.messages import qos

    options = MODES[mode]
    with reserve_ros_domain() as lease, tempfile.TemporaryDirectory() as tmp, \
            Supervisor(isolated_ros_env(lease.domain_id, tree_env(tree)), stop_timeout=5.0) as sup:
        sup.start('bringup', [TOOL, 'bringup', *options] + ([f'{tmp}/bag'] if options[-1:] == ['--record'] else []))
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
    parser.add_argument('--modes', default='multi,single', help=f'of {", ".join(MODES)}')
    parser.add_argument('--baseline', metavar='REV', help='also each mode with the nodes of this git revision, '
                        'alternating with this tree run by run')
    args = parser.parse_args(argv)
    modes = args.modes.split(',')
    unknown = set(modes) - set(MODES)
    if unknown:
        parser.error(f'unknown mode {", ".join(sorted(unknown))}')
    period = contract.StepClock.of(load_machine('micromill_9axis')).period_ns * 1e-9
    with contextlib.ExitStack() as stack:
        trees = labelled_trees(stack, args.baseline)
        results = {(mode, label): [] for mode in modes for label in trees}
        rings = []
        for run in range(args.runs):
            for mode in modes:
                for label, tree in trees.items():
                    whole, moving, wall = helix_rtf(mode, tree)
                    results[mode, label].append((whole, moving))
                    print(f'run {run + 1} {mode}{label}: factor {whole:.3f} over the send ({wall:.1f} s wall), '
                          f'{moving:.3f} moving', flush=True)
            ring = bare_chain_rate(3, multiprocess=True, executor='events') * period
            rings.append(ring)
            print(f'run {run + 1} bare 3-hop ring (a process per node): factor {ring:.3f}', flush=True)
    print(f'\nmedians of {args.runs} runs (micromill_9axis, period {period * 1e6:g} µs):')
    for (mode, label), values in results.items():
        print(f'  {mode}{label}: {statistics.median(v[0] for v in values):.3f} over the send, '
              f'{statistics.median(v[1] for v in values):.3f} moving')
    print(f'  bare 3-hop ring: {statistics.median(rings):.3f}')
    if args.baseline:
        for mode in modes:
            base, this = (statistics.median(v[0] for v in results[mode, label]) for label in trees)
            print(f'  {mode}: this tree {this / base:.2f}x the baseline')


if __name__ == '__main__':
    main()
