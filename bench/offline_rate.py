"""The offline runner's rate (issue [5/8]: >= 5x real time for the 9 axes, no ROS): the
compiled loop (hw_sim/compiled_loop.py) against the Python loop it replaces, measured in
the same run on the same runs, which must agree bit for bit (checked here too).

Runs: the micromill's circle (Yuen Table 6.1 conditions, trajectory.contours.circle) with
the dual stage, and trt_5axis holding home. Each loop runs each case `--repeats` times
after one warm-up run (the compiled loop's first call compiles or loads numba's cache;
that time is printed apart); the median is reported.

    .venv/bin/python bench/offline_rate.py [--steps 30000] [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from hw_sim.offline import run
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.reference import Reference
from trajectory.contours import circle

ROWS = ('reference', 'measured', 'measured_velocity', 'effort', 'true', 'commands', 'offsets')


def same_bits(a, b) -> bool:
    """Every row bit for bit (NaNs aside, hw_sim/compiled_loop.py), the fault, the saturations."""
    for name in ROWS:
        x, y = getattr(a, name), getattr(b, name)
        if x.shape != y.shape or ((x.view(np.int64) != y.view(np.int64)) & ~(np.isnan(x) & np.isnan(y))).any():
            return False
    return (a.fault, a.saturations) == (b.fault, b.saturations)


def timed(machine, reference, steps: int, compiled: bool):
    start = time.perf_counter()
    record = run(machine, reference, steps=steps, compiled=compiled)
    return time.perf_counter() - start, record


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--steps', type=int, default=30000)
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args(argv)
    mill, trt = load_machine('micromill_9axis'), load_machine('trt_5axis')
    cases = [('micromill_9axis circle, dual stage', mill, circle(mill)[0]),
             ('trt_5axis holding home', trt, Reference.hold(trt.axis_names, trt.control_period, trt.home, args.steps))]
    first, _ = timed(mill, cases[0][2], 10, True)
    print(f'compiled loop, first call in this process (numba compile or cache load): {first:.2f} s')
    for label, machine, reference in cases:
        real_time = 1.0 / machine.control_period
        rates = {}
        for compiled in (False, True):
            _, record = timed(machine, reference, min(args.steps, 1000), compiled)       # warm-up
            walls = []
            for _ in range(args.repeats):
                wall, record = timed(machine, reference, args.steps, compiled)
                walls.append(wall)
            rates[compiled] = (args.steps / statistics.median(walls), record)
        (python, a), (fast, b) = rates[False], rates[True]
        same = same_bits(a, b) and b.compiled and not a.compiled
        print(f'{label}, {args.steps} steps at {real_time:,.0f} Hz:')
        print(f'  Python loop (baseline) {python:9,.0f} steps/s = {python / real_time:6.2f}x real time')
        print(f'  compiled loop          {fast:9,.0f} steps/s = {fast / real_time:6.2f}x real time '
              f'({fast / python:.1f}x the baseline); records bit-identical: {same}')
        if not same:
            return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
