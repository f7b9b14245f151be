"""[5/8] Paced by the wall clock: `machine-ctrl bringup MACHINE --paced` (hw_sim steps at real
time, as real hardware does) while the bench moves the machine back and forth; what hw_sim
reports on /diagnostics at the end: missed deadlines (axis-steps without their command at
the next tick), overruns (steps hw_sim itself took late), the step latency (state out to
the step's last command in) and hw_sim's tick lateness, as percentiles over every step
since the graph was ready (hw_sim/pacing.py).

The baseline, measured in the same run and the same way: the bare rclpy ring of two nodes
(bench/ros_chain.py, EventsExecutor like our nodes, a 9-joint JointState), its head paced
by a timer at the same period, in one process and in two — the transport's own round trip
with no computation.

    .venv/bin/python bench/paced_rate.py [--machine trt_5axis] [--seconds 600] [--bare-seconds 60]
                                         [--modes single,multi] [--runs 1] [--baseline REV]

`--baseline REV`: each mode's graph also with the nodes of that git revision (a worktree,
first on PYTHONPATH; the bench's own client is this tree's), alternating with this tree run
by run, so that both see the same machine load.

The moves: joint goals between two points the bench picks inside the strokes (a quarter of
each axis's stroke around its middle, or +-0.1 rad / +-0.01 m where there is no stroke),
sent through a MachineClient in this process and followed to their end; every goal must
succeed (exit status 1 otherwise).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
import time

from baseline import labelled_trees, tree_env
from ros_chain import Chain, PacedHead

from machine_ctrl import contract
from machine_ctrl.app.bringup import client_session
from machine_ctrl.app.goals import follow_goal
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.model.config import load_machine

TOOL = os.path.join(os.path.dirname(sys.executable), 'machine-ctrl')
READY_TIMEOUT = 300.0       # s for bringup to report every node ready
GOAL_TIMEOUT = 120.0        # s (wall) for one move


def goal_points(machine) -> tuple[list[float], list[float]]:
    """Two joint positions to move between (see the module docstring)."""
    low, high = [], []
    for axis in machine.axes:
        if axis.stroke is not None:
            middle, quarter = sum(axis.stroke) / 2, (axis.stroke[1] - axis.stroke[0]) / 8
        else:
            middle, quarter = 0.0, 0.1 if axis.unit == 'rad' else 0.01
        low.append(middle - quarter)
        high.append(middle + quarter)
    return low, high


def bare(multiprocess: bool, period: float, seconds: float) -> dict:
    with Chain(2, multiprocess, 'events', head=PacedHead) as chain:
        chain.head.run_paced(chain.executor, period, 2.0)             # warm-up
        latency, missed, ticks = chain.head.run_paced(chain.executor, period, seconds)
    return {'ticks': ticks, 'missed': missed, 'p50': latency.percentile(50), 'p99': latency.percentile(99),
            'max': latency.maximum}


def paced_graph(machine, single_process: bool, seconds: float, tree=None) -> dict:
    """Bring the graph up paced (its nodes from `tree`, default: as installed), move for
    `seconds`, return hw_sim's diagnostics values after
    the last move and the goals' outcomes. The bench's client joins the ROS graph before the
    nodes start: a participant that joins a running graph costs every process discovery work
    (seen: hw_sim's tick 120-140 ms late in one process), which is not the steady state measured."""
    from diagnostic_msgs.msg import DiagnosticArray

    from machine_ctrl.ros import messages as ros_io
    log_dir = tempfile.mkdtemp(prefix='paced_rate_')
    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id, tree_env(tree)), log_dir=log_dir,
                                                   stop_timeout=30.0) as sup, \
            client_session(machine, 'paced_bench', lease.domain_id) as client:
        last: dict = {}
        received = [0]

        def on_diagnostics(msg) -> None:
            for status in msg.status:
                if status.name == 'hw_sim':
                    last.update({kv.key: kv.value for kv in status.values})
                    received[0] += 1
        client.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, on_diagnostics,
                                        ros_io.qos(contract.DIAGNOSTICS_READER_QOS))
        sup.start('bringup', [TOOL, 'bringup', str(machine.yaml_path), '--paced',
                              *(['--single-process'] if single_process else [])])
        sup.wait_for_line('bringup', 'all nodes ready after', READY_TIMEOUT)
        client.wait_ready()
        client.wait_listening(60.0, publishers=(client.pub_goal,))
        points = goal_points(machine)
        outcomes, start = [], time.monotonic()
        while time.monotonic() - start < seconds:
            target = points[len(outcomes) % 2]
            outcomes.append(follow_goal(client, lambda stamp: client.send_goal(machine.axis_names, [target],
                                                                               stamp=stamp),
                                        GOAL_TIMEOUT, out=io.StringIO()))
            sup.check()
        after = received[0]
        client.wait(lambda: received[0] > after, "hw_sim's diagnostics after the last move", 10.0)
        result = dict(last)
    result['goals'] = len(outcomes)
    result['goals_failed'] = sum(1 for code in outcomes if code != 0)
    return result


def ms(value) -> str:
    return '-' if value in (None, '') else f'{float(value) * 1e3:.3f}'


def report(label: str, seconds: float, ours: dict) -> None:
    print(f'  bringup --paced{label}, {seconds:g} s moving: {ours["goals"]} moves ({ours["goals_failed"]} failed), '
          f'{ours.get("step")} steps, {ours.get("missed_deadlines")} missed deadlines (axis-steps), '
          f'{ours.get("overruns")} overruns', flush=True)
    print(f'  step latency over {ours.get("step_latency_count")} steps: p50 {ms(ours.get("step_latency_p50"))} ms, '
          f'p99 {ms(ours.get("step_latency_p99"))} ms, max {ms(ours.get("step_latency_max"))} ms; tick lateness '
          f'p99 {ms(ours.get("tick_lateness_p99"))} ms, max {ms(ours.get("tick_lateness_max"))} ms; '
          f'fault: {ours.get("fault") or "none"}', flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--machine', default='trt_5axis')
    parser.add_argument('--seconds', type=float, default=600.0, help='moving, per mode and run (default 600)')
    parser.add_argument('--bare-seconds', type=float, default=60.0, help='the bare ring, per mode (default 60)')
    parser.add_argument('--modes', default='single,multi', help='single (one process), multi (a process per node)')
    parser.add_argument('--runs', type=int, default=1, help='graph runs per mode (and tree)')
    parser.add_argument('--baseline', metavar='REV', help='also with the nodes of this git revision, alternating')
    args = parser.parse_args(argv)
    machine = load_machine(args.machine)
    period = machine.control_period
    print(f'{machine.name}: paced at {1 / period:g} Hz; {os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f}',
          flush=True)
    status = 0
    with contextlib.ExitStack() as stack:
        trees = labelled_trees(stack, args.baseline)
        for mode in args.modes.split(','):
            single = mode == 'single'
            ring = bare(not single, period, args.bare_seconds)
            print(f'\n{"one process" if single else "a process per node"}:', flush=True)
            print(f'  bare 2-node ring, {args.bare_seconds:g} s: {ring["ticks"]} ticks, {ring["missed"]} missed; '
                  f'round trip p50 {ms(ring["p50"])} ms, p99 {ms(ring["p99"])} ms, max {ms(ring["max"])} ms', flush=True)
            for run in range(args.runs):
                for label, tree in trees.items():
                    ours = paced_graph(machine, single, args.seconds, tree)
                    report(label + (f', run {run + 1}' if args.runs > 1 else ''), args.seconds, ours)
                    status |= bool(ours['goals_failed'])
    print(f'\nload average at the end {os.getloadavg()[0]:.2f}')
    return status


if __name__ == '__main__':
    raise SystemExit(main())
