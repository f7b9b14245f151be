"""The experiments' independent runs in parallel processes (machine_ctrl/experiments/parallel.py):
`machine-ctrl experiment square` and `frf` on the micromill with the runs one after another
in this process (--jobs 1, the baseline, measured in the same run) and in up to N processes
(default: the available CPUs). Prints the wall times, the speed-up and whether the results
are equal bit for bit (they must be). No timing asserts.

    .venv/bin/python bench/experiment_jobs.py [--jobs N]
"""
from __future__ import annotations

import argparse
import time

from machine_ctrl.experiments import parallel, tracking
from machine_ctrl.model.config import load_machine


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--jobs', type=int, default=parallel.available_cpus())
    args = ap.parse_args()
    machine = load_machine('micromill_9axis')
    for label, experiment in (('square', lambda workers: tracking.contouring(machine, 'square', workers=workers)),
                              ('frf', lambda workers: tracking.frf(machine, workers=workers))):
        seconds, results = {}, {}
        for workers in (1, args.jobs):
            t0 = time.perf_counter()
            results[workers] = experiment(workers)
            seconds[workers] = time.perf_counter() - t0
        same = results[1] == results[args.jobs]
        print(f'experiment {label}: --jobs 1 {seconds[1]:.1f} s, --jobs {args.jobs} {seconds[args.jobs]:.1f} s '
              f'({seconds[1] / seconds[args.jobs]:.2f}x); results ' + ('bit-identical' if same else 'DIFFER'),
              flush=True)


if __name__ == '__main__':
    main()
