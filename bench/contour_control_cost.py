"""Cost of the cross-coupled contour control (machine_ctrl/control/contour_coupling.py) per
control step, beside its baseline measured in the same run: the offline runner's step without
it (plant, dual stage, servos). For each machine with a contour_control section, the first
STEPS steps of its experiment path (trt_5axis: Eq. 35; micromill_9axis: the circle of
Table 6.1), process time per step (median of R repeats), plain and coupled; the coupled run
includes the reference conversion of the rows it uses (tool_reference, per 500-row block).

    .venv/bin/python bench/contour_control_cost.py [--steps N] [--repeat R]
"""
import argparse
import os
import statistics
import time

from hw_sim.offline import run
from machine_ctrl.model.config import load_machine


def reference_of(machine):
    if machine.name == 'trt_5axis':
        from trajectory.sencer_path import sencer_reference
        return sencer_reference(machine)
    from trajectory.contours import circle
    return circle(machine)[0]


def per_step(machine, reference, steps, repeat, coupled):
    times = []
    for _ in range(repeat):
        start = time.process_time()
        run(machine, reference, steps=steps, contour_control=coupled)
        times.append((time.process_time() - start) / steps)
    return statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument('--steps', type=int, default=5000)
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args(argv)
    print(f'load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; process time per step, '
          f'median of {args.repeat}, first {args.steps} steps')
    print(f'{"machine":18s} {"period us":>9s} {"plain us":>9s} {"coupled us":>11s} {"added us":>9s} '
          f'{"added/period":>12s}')
    for name in ('trt_5axis', 'micromill_9axis'):
        machine = load_machine(name)
        reference = reference_of(machine)
        steps = min(args.steps, len(reference))
        plain = per_step(machine, reference, steps, args.repeat, False)
        coupled = per_step(machine, reference, steps, args.repeat, True)
        period = machine.control_period
        print(f'{name:18s} {period * 1e6:9.0f} {plain * 1e6:9.1f} {coupled * 1e6:11.1f} '
              f'{(coupled - plain) * 1e6:9.1f} {(coupled - plain) / period:12.2f}')


if __name__ == '__main__':
    main()
