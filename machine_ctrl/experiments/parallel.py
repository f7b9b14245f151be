"""An experiment's independent offline runs side by side, one process each.

The runs of an experiment share nothing: each builds its own simulator, whose random sources
are seeded from the machine config (simulation.seed), and its own laws. So the results are
the same, bit for bit, whether the runs go one after another here or in other processes in
any order (test/test_experiments.py compares both). Processes are started fresh ('spawn'):
a forked copy of a process that runs ROS threads is not safe.
"""
from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Iterable, Sequence


def available_cpus() -> int:
    """The CPUs this process may run on (its affinity, not the machine's count)."""
    return len(os.sched_getaffinity(0))


def run_all(function: Callable, jobs: Iterable[Sequence], workers: int | None = None,
            done: Callable[[int], None] | None = None) -> list:
    """[function(*job) for job in jobs], computed in up to `workers` processes (default: the
    available CPUs; 1, or a single job: here, in this process). `function` must be a module's
    top-level function and the jobs picklable. `done(i)` is called, in job order, once job i's
    result is in. An exception of a job is raised here, as it would be in a loop."""
    jobs = [tuple(job) for job in jobs]
    workers = available_cpus() if workers is None else workers
    if workers < 1:
        raise ValueError(f'workers must be a whole number > 0, got {workers}')
    results = []
    if min(workers, len(jobs)) <= 1:
        for i, job in enumerate(jobs):
            results.append(function(*job))
            if done is not None:
                done(i)
        return results
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=multiprocessing.get_context('spawn')) as pool:
        for i, result in enumerate(pool.map(function, *zip(*jobs))):
            results.append(result)
            if done is not None:
                done(i)
    return results
