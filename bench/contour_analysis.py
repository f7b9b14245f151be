"""[5/8] What `machine-ctrl analyze` spends on the contour error (recording.analysis.contour_errors:
each measured tool tip's distance from the reference polyline, its nearest vertex searched within
CONTOUR_WINDOW = 50 ms of its own step), against the former implementation in the same run.

    .venv/bin/python bench/contour_analysis.py [--runs 3]

The former one (kept below as the baseline) summed the squared differences over a (rows,
columns, 3) array and masked the whole band; the current one sums per coordinate in place and
masks only the band's corners. Both must give the same bits: checked on every case. Cases (a
helix with 10 nm of noise on the measured points; the sizes of real bags):

* fts_lathe, 199.6 kHz: 19,000 steps, window 9,980 (test_freeform_graph's bag);
* micromill, 10 kHz: 36,000 steps (the demo's helix turn), window 500.
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from machine_ctrl.recording.analysis import contour_errors


def former(path: np.ndarray, points: np.ndarray, window: int) -> np.ndarray:
    """contour_errors as it was before 2026-12-07 (the baseline)."""
    n, last = len(points), len(path) - 1
    result = np.empty(n)
    for start in range(0, n, 512):
        stop = min(start + 512, n)
        lo, hi = max(start - window, 0), min(stop + window, last + 1)
        block = points[start:stop]
        d2 = ((block[:, None, :] - path[None, lo:hi, :]) ** 2).sum(axis=2)
        index = np.arange(start, stop)[:, None]
        d2[np.abs(np.arange(lo, hi)[None, :] - index) > window] = np.inf
        nearest = lo + np.argmin(d2, axis=1)
        best = np.sqrt(d2[np.arange(stop - start), nearest - lo])
        for j in (np.maximum(nearest - 1, 0), np.minimum(nearest, max(last - 1, 0))):
            if last < 1:
                break
            p0, d = path[j], path[j + 1] - path[j]
            length2 = np.einsum('ij,ij->i', d, d)
            u = np.einsum('ij,ij->i', block - p0, d) / np.where(length2 > 0, length2, 1.0)
            foot = p0 + np.clip(u, 0.0, 1.0)[:, None] * d
            best = np.minimum(best, np.linalg.norm(block - foot, axis=1))
        result[start:stop] = best
    return result


def case(steps: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.0, steps)
    path = np.column_stack([1e-3 * np.cos(6 * t), 1e-3 * np.sin(6 * t), 1e-4 * t])
    return path, path + 1e-8 * np.random.default_rng(1).standard_normal(path.shape)


def timed(function, *args) -> tuple[float, np.ndarray]:
    start = time.perf_counter()
    result = function(*args)
    return time.perf_counter() - start, result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    runs = parser.parse_args().runs
    print('| case | steps | window | former (s, median) | current (s, median) | speed-up | same bits |')
    print('|---|---:|---:|---:|---:|---:|---|')
    for name, steps, window in (('fts_lathe 199.6 kHz', 19000, 9980), ('micromill 10 kHz', 36000, 500)):
        path, points = case(steps)
        times = {'former': [], 'current': []}
        same = True
        for _ in range(runs):
            t_old, old = timed(former, path, points, window)
            t_new, new = timed(contour_errors, path, points, window)
            times['former'].append(t_old)
            times['current'].append(t_new)
            same = same and np.array_equal(old, new)
        a, b = statistics.median(times['former']), statistics.median(times['current'])
        print(f'| {name} | {steps} | {window} | {a:.2f} | {b:.2f} | {a / b:.1f} | {same} |')


if __name__ == '__main__':
    main()
