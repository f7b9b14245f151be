"""Geometric error measurements: a simulated laser-interferometer campaign and the
measurement CSV (Yuen thesis, seed 000_d9dd5f6a818770e4.txt, §5.3 and §6.4).

Campaign (thesis §5.3): every error of every axis in the error map is measured at 1 mm steps
over the axis's range, 6 times; roll (rotation about the axis's own direction) is not
measured: a laser interferometer cannot (thesis §6.4, "this error was set to 0"). Each
reading is the true error plus Gaussian noise, seeded from the machine config
(simulation.seed), one stream per axis and error. Straightness is read against the machine's
nominal directions, so it includes the squareness of the axis (error_map.py); the fit then
carries the squareness in the straightness polynomials.

CSV (comma separated, one reading per line, SI units; lines starting with # are comments):

    axis,error,position,repeat,value
    x_c,dx,-0.04,1,1.234e-07

axis: a machine axis; error: dx dy dz (m) or ex ey ez (rad), see error_map.py; position:
axis position (m); repeat: run number 1, 2, ...; value: the reading. Within each repeat of
an (axis, error) the positions are strictly increasing, and every repeat has the same
positions. Columns may come in any order; extra columns are ignored.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compensation.error_map import ERROR_NAMES, ErrorMap
from compensation.error_model import ErrorKinematics

COLUMNS = ('axis', 'error', 'position', 'repeat', 'value')
STEP = 1e-3            # m, thesis §5.3: "every 1[mm]"
REPEATS = 6            # thesis §5.3: "the errors are measured 6 times"
# assumed: reading noise of the interferometer (1 sigma): 50 nm for the linear and
# straightness optics, 0.5 urad for the angular optics (typical laser-system repeatability;
# the seeds state none).
NOISE_DISPLACEMENT = 50e-9
NOISE_ROTATION = 0.5e-6
QUINTIC_POINTS = 6     # Eq. (5.10): six coefficients need six distinct positions


class MeasurementError(ValueError):
    """A measurement file we refuse; the text is one line naming file, line and problem."""


@dataclass(frozen=True)
class Series:
    """Readings of one (axis, error): positions (N,) and values (repeats, N) (Eq. 5.9)."""
    axis: str
    error: str
    positions: np.ndarray
    values: np.ndarray


def measurable(model: ErrorKinematics, axis: str) -> tuple[str, ...]:
    """Errors a laser interferometer measures on a linear axis: all but the roll."""
    roll = 'e' + 'xyz'[model.direction(axis)]
    return tuple(e for e in ERROR_NAMES if e != roll)


def campaign(model: ErrorKinematics, error_map: ErrorMap, seed: int) -> list[Series]:
    """The simulated campaign on the machine `model` (the true map) over the map's ranges."""
    out = []
    for axis, errors in error_map.axes.items():
        lo, hi = errors.range
        positions = lo + STEP * np.arange(int(round((hi - lo) / STEP)) + 1)
        truth = model.axis_errors(axis, positions)
        for error in measurable(model, axis):
            i = ERROR_NAMES.index(error)
            sigma = NOISE_DISPLACEMENT if i < 3 else NOISE_ROTATION
            rng = np.random.default_rng([seed, model.axis_names.index(axis), i])
            out.append(Series(axis, error, positions,
                              truth[:, i] + sigma * rng.standard_normal((REPEATS, len(positions)))))
    return out


def write_csv(path: str | Path, series: list[Series], comment: str = '') -> None:
    with open(path, 'w', newline='') as f:
        for line in comment.splitlines():
            f.write(f'# {line}\n')
        writer = csv.writer(f, lineterminator='\n')
        writer.writerow(COLUMNS)
        for s in series:
            for r, row in enumerate(s.values, start=1):
                for q, v in zip(s.positions, row):
                    writer.writerow((s.axis, s.error, repr(float(q)), r, repr(float(v))))


def read_csv(path: str | Path, axis_names) -> list[Series]:
    """Series of a measurement CSV; MeasurementError naming the file, line and problem."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise MeasurementError(f'{path}: cannot read: {" ".join(str(exc).split())}') from None
    numbered = [(n, line) for n, line in enumerate(lines, start=1)
                if line.strip() and not line.lstrip().startswith('#')]
    if not numbered:
        raise MeasurementError(f'{path}: no header line ({",".join(COLUMNS)})')
    header_line, header = numbered[0][0], [c.strip() for c in next(csv.reader([numbered[0][1]]))]
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise MeasurementError(f'{path}:{header_line}: missing column(s) {", ".join(missing)} '
                               f'(need {",".join(COLUMNS)})')
    index = [header.index(c) for c in COLUMNS]
    runs: dict[tuple[str, str], dict[int, list[tuple[float, float, int]]]] = {}
    for n, line in numbered[1:]:
        axis, error, position, repeat, value = _row(path, n, next(csv.reader([line])), index, axis_names)
        run = runs.setdefault((axis, error), {}).setdefault(repeat, [])
        if run and position <= run[-1][0]:
            raise MeasurementError(f'{path}:{n}: {axis} {error} repeat {repeat}: position {position!r} '
                                   f'is not after the previous one {run[-1][0]!r} (must increase)')
        run.append((position, value, n))
    if not runs:
        raise MeasurementError(f'{path}: no readings')
    return [_series(path, axis, error, reps) for (axis, error), reps in runs.items()]


def _row(path, n, cells, index, axis_names):
    if len(cells) <= max(index):
        raise MeasurementError(f'{path}:{n}: {len(cells)} columns, the header has more')
    axis, error, position, repeat, value = (cells[i].strip() for i in index)
    if axis not in axis_names:
        raise MeasurementError(f'{path}:{n}: unknown axis {axis!r} (axes: {", ".join(axis_names)})')
    if error not in ERROR_NAMES:
        raise MeasurementError(f'{path}:{n}: unknown error {error!r} (one of {", ".join(ERROR_NAMES)})')
    numbers = []
    for name, text in (('position', position), ('value', value)):
        try:
            number = float(text)
        except ValueError:
            raise MeasurementError(f'{path}:{n}: {name} {text!r} is not a number') from None
        if not math.isfinite(number):
            raise MeasurementError(f'{path}:{n}: {name} is {text} (must be finite)')
        numbers.append(number)
    if not repeat.isdigit() or int(repeat) < 1:
        raise MeasurementError(f'{path}:{n}: repeat {repeat!r} must be a whole number >= 1')
    return axis, error, numbers[0], int(repeat), numbers[1]


def _series(path, axis, error, reps) -> Series:
    first = sorted(reps)[0]
    positions = [p for p, _, _ in reps[first]]
    for r, run in sorted(reps.items()):
        if [p for p, _, _ in run] != positions:
            raise MeasurementError(f'{path}:{run[0][2]}: {axis} {error} repeat {r} has other positions '
                                   f'than repeat {first}')
    if len(positions) < QUINTIC_POINTS:
        raise MeasurementError(f'{path}:{reps[first][0][2]}: {axis} {error}: {len(positions)} positions, '
                               f'a quintic (Eq. 5.10) needs at least {QUINTIC_POINTS}')
    values = np.array([[v for _, v, _ in run] for _, run in sorted(reps.items())])
    return Series(axis, error, np.array(positions), values)
