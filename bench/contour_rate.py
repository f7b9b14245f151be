"""Cost of the contour-error estimators per control step, beside the control period, for
each machine: the per-step part (FK of the measured axes + tool-tip estimate + orientation
estimate, ContourEstimator.update) and the reference conversion (tool_reference, done when
a chunk arrives, amortized per row). Median over repeats of a run along a real reference
(trt_5axis: Eq. 35; micromill_9axis: the first rows of the [3/7] helix) with the machine's
measured axes from the offline runner.

    .venv/bin/python bench/contour_rate.py [--rows N] [--repeat R]
"""
import argparse
import os
import statistics
import time

from machine_ctrl.model.config import load_machine
from machine_ctrl.contour.estimation import ESTIMATORS, ContourEstimator, ToolTrajectory, tool_reference
from machine_ctrl.model.kinematics import Kinematics
from hw_sim.offline import run


def reference_of(name):
    machine = load_machine(name)
    if name == 'trt_5axis':
        from trajectory.sencer_path import sencer_reference
        return machine, sencer_reference(machine)
    from trajectory.planner import plan
    return machine, plan('helix', machine).unwrap().reference


def per_row(fn, rows, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) / rows)
    return statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument('--rows', type=int, default=3000)
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args(argv)
    print(f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; median of {args.repeat} runs '
          f'of {args.rows} steps (us per step)')
    print(f'| machine | control period | reference conversion | {" | ".join(ESTIMATORS)} | worst total / period |')
    print('|---|---:|---:|' + '---:|' * len(ESTIMATORS) + '---:|')
    for name in ('trt_5axis', 'micromill_9axis'):
        machine, reference = reference_of(name)
        rows = min(args.rows, len(reference))
        start = (len(reference) - rows) // 2 if name == 'trt_5axis' else 0
        kinematics = Kinematics.from_config(machine)
        record = run(machine, reference, steps=start + rows)
        window = slice(start, start + rows)
        conversion = per_row(lambda: tool_reference(kinematics, reference.position[window],
                                                    reference.velocity[window],
                                                    reference.acceleration[window]), rows, args.repeat)
        trajectory = ToolTrajectory.from_reference(kinematics, reference)
        measured = record.measured[window].tolist()
        costs = []
        for method in ESTIMATORS:
            def estimate():
                estimator = ContourEstimator(kinematics, method)
                for k, q in enumerate(measured, start):
                    estimator.update(trajectory, k, q)
            costs.append(per_row(estimate, rows, args.repeat))
        period = machine.control_period
        print(f'| {name} | {period * 1e6:.0f} | {conversion * 1e6:.1f} | '
              + ' | '.join(f'{c * 1e6:.1f}' for c in costs) + f' | {(conversion + max(costs)) / period:.2f} |')


if __name__ == '__main__':
    main()
