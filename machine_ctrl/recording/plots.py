"""PNG plots of analysis results (matplotlib, Agg backend: no display needed).

* ``errors.png``: the linear axes' tracking errors (axes without any left out) and the
  tool-tip contour error over time.
* ``path_xy.png``: the reference tool path in x-y and the measured one with its deviation
  magnified (factor in the title) so sub-um errors are visible on a mm path.
* ``limits.png``: peak |v|, |a|, |j| over the limits per axis (reference and measured).

With two results, each figure shows both (labels [1] and [2]).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

# assumed: the magnified deviation's largest value is drawn as 5 % of the path's extent
MAGNIFIED_FRACTION = 0.05


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def write(results: list[dict], machine, directory) -> list[Path]:
    """Write the three figures into `directory` (created); returns their paths."""
    plt = _pyplot()
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = [_errors(plt, results, machine, directory / 'errors.png'),
             _path(plt, results, directory / 'path_xy.png'),
             _limits(plt, results, machine, directory / 'limits.png')]
    return paths


def _errors(plt, results, machine, path: Path) -> Path:
    names = list(machine.axis_names)
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for n, r in enumerate(results, 1):
        s = r['series']
        t = s['steps'] * machine.control_period
        for i, axis in enumerate(names):
            if np.any(s['errors'][:, i]) and machine.axis(axis).kind == 'linear':
                axes[0].plot(t, s['errors'][:, i] * 1e6, lw=0.6, label=f'[{n}] {axis}')
        axes[1].plot(t, s['contour'] * 1e6, lw=0.6, label=f'[{n}] tool-tip contour')
    axes[0].set_ylabel('tracking error [um]')
    axes[1].set_ylabel('contour error [um]')
    axes[1].set_xlabel('time [s]')
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=4)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _path(plt, results, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 7))
    ref = results[0]['series']['tool_ref']
    extent = float(np.ptp(ref[:, :2], axis=0).max()) or 1e-3
    largest = max(float(np.linalg.norm(r['series']['tool_meas'] - r['series']['tool_ref'], axis=1).max())
                  for r in results) or 1e-9
    gain = MAGNIFIED_FRACTION * extent / largest
    ax.plot(ref[:, 0] * 1e3, ref[:, 1] * 1e3, 'k-', lw=0.8, label='reference')
    for n, r in enumerate(results, 1):
        s = r['series']
        shown = s['tool_ref'] + gain * (s['tool_meas'] - s['tool_ref'])
        ax.plot(shown[:, 0] * 1e3, shown[:, 1] * 1e3, lw=0.6, label=f'[{n}] measured')
    ax.set_title(f'tool tip x-y, deviation magnified {gain:.3g}x')
    ax.set_xlabel('x [mm]')
    ax.set_ylabel('y [mm]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _limits(plt, results, machine, path: Path) -> Path:
    names = list(machine.axis_names)
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    width = 0.8 / (2 * len(results))
    x = np.arange(len(names))
    for row, key in enumerate(('velocity', 'acceleration', 'jerk')):
        for n, r in enumerate(results):
            for m, source in enumerate(('reference', 'measured')):
                values = [r['limits'][source][a][key] for a in names]
                offset = (2 * n + m - (2 * len(results) - 1) / 2) * width
                axes[row].bar(x + offset, values, width, label=f'[{n + 1}] {source}')
        axes[row].axhline(1.0, color='r', lw=0.8)
        axes[row].set_yscale('symlog', linthresh=0.01)
        axes[row].set_ylabel(f'peak |{key[0]}| / limit')
        axes[row].grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, ncol=4)
    axes[-1].set_xticks(x, names)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
