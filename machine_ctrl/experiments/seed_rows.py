"""The rows of the seed tables (``machine-ctrl experiment`` fts-*, piezo-milling, deflection,
feed-force, midrange): a reproduced figure, the
seed's value beside ours, their ratio, and the reason printed when they differ by more than
the tolerance (30 % by default: the issues' rule for saying why)."""
from __future__ import annotations

import math


def seed_row(name: str, seed, ours: float, unit: str = '', note_if_off: str = '', tol: float = 0.30) -> dict:
    """`seed` a value or a (low, high) range; `off` when ours is outside it by more than `tol`."""
    if isinstance(seed, tuple):
        lo, hi = seed
        ratio = ours / (0.5 * (lo + hi))
        off = not (lo * (1 - tol) <= ours <= hi * (1 + tol))
    else:
        ratio = ours / seed if seed else float('nan')
        off = not (abs(ratio - 1) <= tol) if math.isfinite(ratio) else True
    return {'name': name, 'seed': seed, 'ours': ours, 'ratio': ratio, 'unit': unit,
            'note': note_if_off if off else '', 'off': bool(off)}


def row_text(row: dict, width: int = 48) -> str:
    """One printed line: name, seed, ours, ratio, unit, and the note when off."""
    seed = row['seed']
    seed = f'{seed[0]:g}-{seed[1]:g}' if isinstance(seed, tuple) else f'{seed:.4g}'
    return (f'{row["name"]:<{width}} {seed:>8} {row["ours"]:>9.4g} {row["ratio"]:>7.3f}  {row["unit"]}'
            + (f'  > 30 %: {row["note"]}' if row['off'] else ''))


def two_panels(directory):
    """(matplotlib's pyplot, a figure with two side-by-side axes) for a seed table's PNG, the
    directory made; :func:`save_figure` writes it."""
    import os

    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    os.makedirs(directory, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    return plt, fig, axes


def save_figure(plt, fig, directory, name: str, wspace: float = 0.22) -> str:
    """Write `fig` as DIRECTORY/NAME (the seed tables' layout and resolution; `wspace`
    between the panels), close it; the path."""
    import os
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.11, top=0.96, wspace=wspace)
    path = os.path.join(directory, name)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def print_table(reproduce, format_table) -> int:
    """``python -m`` of a seed-table experiment: its table on stdout; exit 0, or 1 when it failed."""
    result = reproduce()
    print(format_table(result))
    return 0 if result['status'] == 'ok' else 1
