"""Geometric error maps: the six errors of each axis as functions of that axis's position
(Yuen thesis, seed 000_d9dd5f6a818770e4.txt, Eq. 5.1, Fig. 5.1) plus squareness errors
between axes (the "21 geometric errors" of §6.4), read from and written to YAML.

One format serves the simulated machine's true map (``config/error_maps/``) and the model
fitted from measurements (``machine-ctrl fit-errors --out``).

Errors of an axis, in the axis's own frame after its motion (Eq. 5.1), SI units:
    dx, dy, dz   displacements delta_x, delta_y, delta_z (m): positioning along the axis,
                 straightness across it
    ex, ey, ez   small rotations epsilon_x, epsilon_y, epsilon_z (rad): roll about the axis,
                 pitch and yaw about the other two
Each is a polynomial (Eq. 5.13, coefficients highest power first) in the normalized position
u = (2 q - lo - hi) / (hi - lo), which is -1..1 over the axis's measured range [lo, hi] (m):
each coefficient is the size of its term at the range ends, and the least-squares fit
(Eq. 5.12) is well conditioned. Outside the range the error is held at its end value
(assumed: nothing is known there, and a quintic extrapolates wildly).

Squareness (rad): the direction of motion of `axis` is tilted by a small angle about the
base direction `about` (ISO 230-1 out-of-squareness), i.e. its displacement q u becomes
q (u + gamma e_about x u): a straightness error growing linearly with the position.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from machine_ctrl.model.config import _Loader, _Section
from machine_ctrl.model.errors import ConfigError

ERROR_NAMES = ('dx', 'dy', 'dz', 'ex', 'ey', 'ez')
DIRECTIONS = {'x': 0, 'y': 1, 'z': 2}
KIND = 'geometric_error_map'
# assumed: degree <= 9 in a map (a quintic is fitted, Eq. 5.10; a true map may be richer).
MAX_DEGREE = 9


@dataclass(frozen=True)
class AxisErrors:
    """The six error polynomials of one axis over its range (see the module docstring)."""
    range: tuple[float, float]                        # m (or rad), lo < hi
    coefficients: dict[str, tuple[float, ...]]        # error name -> highest power first

    def normalized(self, q) -> np.ndarray:
        lo, hi = self.range
        return (2.0 * np.clip(q, lo, hi) - lo - hi) / (hi - lo)

    def evaluate(self, q) -> np.ndarray:
        """(N, 6) errors [dx dy dz ex ey ez] at positions q (N,), Horner in u."""
        q = np.asarray(q, float)
        if q.shape == (1,):                 # the simulator's one state per step: the same
            return self._evaluate_one(float(q[0]))   # arithmetic in floats, ~10x faster
        u = self.normalized(q)
        out = np.zeros((u.shape[0], 6))
        for i, name in enumerate(ERROR_NAMES):
            for c in self.coefficients.get(name, ()):
                out[:, i] = out[:, i] * u + c
        return out

    def _evaluate_one(self, q: float) -> np.ndarray:
        lo, hi = self.range
        u = (2.0 * min(max(q, lo), hi) - lo - hi) / (hi - lo)
        out = [0.0] * 6
        for i, name in enumerate(ERROR_NAMES):
            for c in self.coefficients.get(name, ()):
                out[i] = out[i] * u + c
        return np.array([out])


@dataclass(frozen=True)
class Squareness:
    axis: str
    about: str          # 'x' | 'y' | 'z' (base directions)
    angle: float        # rad


@dataclass(frozen=True)
class ErrorMap:
    axes: dict[str, AxisErrors] = field(default_factory=dict)
    squareness: tuple[Squareness, ...] = ()
    source: str = ''                                  # file it was read from, for messages


def load_error_map(path: str | Path, axis_names) -> ErrorMap:
    """Read an error map; ConfigError with one line ``<file>: <key>: <problem>``."""
    path = Path(path)
    try:
        raw = yaml.load(path.read_text(), Loader=_Loader)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f'{path}: cannot read: {" ".join(str(exc).split())}') from None
    top = _Section(raw, path, '')
    if top.string('kind') != KIND:
        top.fail(f'must be {KIND}', 'kind')
    axes_section = top.section('axes')
    axes = {}
    for name in map(str, axes_section.data):
        if name not in axis_names:
            axes_section.fail(f'unknown axis (axes: {", ".join(axis_names)})', name)
        axes[name] = _axis_errors(axes_section.section(name))
    axes_section.finish()
    squareness = ()
    if 'squareness' in top.data:
        squareness = _squareness(top, axis_names)
    top._used.add('squareness')
    top.finish()
    return ErrorMap(axes, squareness, str(path))


def _axis_errors(s: _Section) -> AxisErrors:
    raw = s._get('range', None)
    if not isinstance(raw, list) or len(raw) != 2:
        s.fail(f'must be [lo, hi], got {raw!r}', 'range')
    pair = _Section({'lo': raw[0], 'hi': raw[1]}, s.file, f'{s.key}.range')
    lo, hi = pair.number('lo'), pair.number('hi')
    if not lo < hi:
        s.fail(f'lo must be < hi, got [{lo:g}, {hi:g}]', 'range')
    coefficients = {}
    for name in ERROR_NAMES:
        if name in s.data:
            coefficients[name] = _coefficients(s, name)
    s.finish()
    return AxisErrors((lo, hi), coefficients)


def _coefficients(s: _Section, name: str) -> tuple[float, ...]:
    raw = s._get(name, None)
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_DEGREE + 1:
        s.fail(f'must be a list of 1..{MAX_DEGREE + 1} coefficients, got {raw!r}', name)
    values = _Section({str(i): v for i, v in enumerate(raw)}, s.file, f'{s.key}.{name}')
    return tuple(values.number(str(i)) for i in range(len(raw)))


def _squareness(top: _Section, axis_names) -> tuple[Squareness, ...]:
    raw = top._get('squareness', None)
    if not isinstance(raw, list):
        top.fail('must be a list of {axis, about, angle}', 'squareness')
    out = []
    for i, item in enumerate(raw):
        s = _Section(item, top.file, f'squareness[{i}]')
        entry = Squareness(s.string('axis', choices=tuple(axis_names)),
                           s.string('about', choices=tuple(DIRECTIONS)), s.number('angle'))
        s.finish()
        out.append(entry)
    return tuple(out)


def dump_error_map(error_map: ErrorMap, header: str = '') -> str:
    """YAML text of a map (floats as shortest round-trip repr: a reload is exact)."""
    lines = [f'# {line}' for line in header.splitlines()]
    lines += [f'kind: {KIND}', 'axes:']
    for name, errors in error_map.axes.items():
        lo, hi = errors.range
        lines.append(f'  {name}:')
        lines.append(f'    range: [{lo!r}, {hi!r}]')
        for error in ERROR_NAMES:
            if error in errors.coefficients:
                lines.append(f'    {error}: [{", ".join(repr(float(c)) for c in errors.coefficients[error])}]')
    if error_map.squareness:
        lines.append('squareness:')
        lines += [f'  - {{axis: {s.axis}, about: {s.about}, angle: {s.angle!r}}}' for s in error_map.squareness]
    return '\n'.join(lines) + '\n'
