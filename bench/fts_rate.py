"""Wall time of one simulated second of the fts_lathe machine on the offline runner
(hw_sim/offline.py) at its 199.6 kHz control period (issue [3/8]: <= 10 s wall), every axis
stepped: plants (W: the Table 5-2 flexure stage with its current loop, sensor and noise;
hw_sim/flexure.py), sensors, servo laws (W: the Ch. 7 PID), the Z + W coupling. The
reference: W a 20 Hz sine of 5 um amplitude (Ding Ch. 8: "following error < 25 nm for
20 Hz motions"), C, X, Z at rest. Baseline in the same run: the 9-axis micromill's
offline rate at its 10 kHz period (steps per second).

    .venv/bin/python bench/fts_rate.py [SECONDS]
"""
from __future__ import annotations

import sys
import time

import numpy as np

from hw_sim import offline
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.reference import Reference
from trajectory.freeform import axis_sine


def timed_run(machine, reference) -> tuple[float, offline.RunRecord]:
    start = time.perf_counter()
    record = offline.run(machine, reference)
    return time.perf_counter() - start, record


def main(argv=None) -> int:
    seconds = float((argv or sys.argv[1:] or ['1.0'])[0])
    mill = load_machine('micromill_9axis')
    base_wall, _ = timed_run(mill, Reference.hold(mill.axis_names, mill.control_period, mill.home, 20000))
    lathe = load_machine('fts_lathe')
    reference = axis_sine(lathe, 'w', 5e-6, 20.0, seconds)
    wall, record = timed_run(lathe, reference)
    w = lathe.axis_names.index('w')
    settled = slice(len(reference) // 2, None)     # past the start transient (the sine starts at full speed)
    following = (record.reference[:, w] - record.measured[:, w])[settled]
    real = (record.reference[:, w] - record.true[:, w])[settled]
    steps = len(reference)
    print(f'baseline: micromill_9axis offline {20000 / base_wall:,.0f} steps/s (10 kHz period)')
    print(f'fts_lathe: {seconds:g} s at {1 / lathe.control_period:,.0f} Hz = {steps:,} steps in {wall:.2f} s wall '
          f'({steps / wall:,.0f} steps/s; target <= {10 * seconds:g} s)')
    print(f'W 20 Hz, 5 um sine, second half: max |following error| {np.abs(following).max() * 1e9:.2f} nm, '
          f'RMS {following.std() * 1e9:.3f} nm; max |real error| {np.abs(real).max() * 1e9:.2f} nm '
          f'(Ding Ch. 8: following error < 25 nm); fault: {record.fault}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
