"""Cutter-location (CL) data: the toolpath input of trajectory generation (issue [3/7]).

CL data are N tool-tip positions P (N, 3, m) and unit tool axes O (N, 3), pointing from the
tip towards the spindle, in the workpiece frame (Yuen thesis, seed 000, section 3.3: "the
tooltip position and tool orientation with respect to the workpiece, also known as cutter
location (CL) data"). Sources: a CSV file (`read_csv`), arrays (`from_arrays`, used by the
nav_msgs/Path converter with `axes_from_quaternions`) or a built-in test path (`builtin`).

Plain numpy, no rclpy.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

# Fewest points a path may have: the quintic (degree k = 5) interpolating spline of
# trajectory.spline needs k + 1 = 6 (with 6 points it is the one quintic polynomial through
# them; scipy's make_interp_spline refuses fewer without end derivatives). Nothing after the
# fit depends on the number of points (the resolution has its own grid).
MIN_POINTS = 6

# m. Consecutive points closer than this are a repeated point (degenerate arc length).
# assumed: 1 nm, far below the 20 nm table sensors (CIRP seed 002 section 2) and far above
# float rounding of coordinates of a 100 mm machine (~1e-17 m).
MIN_SPACING = 1e-9

# A tool axis (or quaternion) shorter than this is zero-length.
# assumed: 1e-9; shorter vectors are zero up to rounding of typical inputs.
MIN_AXIS_NORM = 1e-9
# A number beyond this has a square that overflows a float (1e154² > 1.8e308), so no distance
# or norm can be taken of it: a tool tip with such a coordinate is refused at once (one within
# it but out of the machine's reach is the planner's to refuse, naming the reach), a tool axis
# with such a component is scaled before its norm is taken.
HUGE = 1e150

# An orientation quaternion (x, y, z, w) is unit when |x² + y² + z² + w² - 1| is below this:
# tf2's QUATERNION_NORMALIZATION_TOLERANCE (ros2/geometry2, tf2/src/buffer_core.cpp, 10e-3 on
# the squared norm; rviz's validateQuaternions uses the same), so a pose tf2 accepts is
# accepted here; it is then normalized.
QUATERNION_TOLERANCE = 10e-3

COLUMNS = ('px', 'py', 'pz', 'oi', 'oj', 'ok')

# rad, a_f / b_f stroke +-0.5 deg (seed-notes.md "Strokes", thesis seed 000 / CIRP seed 002).
TABLE_TILT_LIMIT = math.radians(0.5)
# rad. assumed: generated paths tilt the tool at most 0.25 deg, half the table's reach,
# leaving the redundancy resolution room (issue [3/7] asks for <= 0.3 deg).
GENERATED_TILT = math.radians(0.25)


class CLDataError(ValueError):
    """Bad CL data; `index` is the offending point (0-based) when there is one."""

    def __init__(self, message: str, index: int | None = None):
        super().__init__(message)
        self.index = index


@dataclass(frozen=True)
class CLData:
    """Validated CL data. `axes` are normalized on construction."""
    positions: np.ndarray  # (N, 3) m, tool tip, workpiece frame
    axes: np.ndarray       # (N, 3) unit, tip -> spindle, workpiece frame

    def __post_init__(self):
        p = np.array(self.positions, dtype=float)
        o = np.array(self.axes, dtype=float)
        for name, a in (('positions', p), ('axes', o)):
            if a.ndim != 2 or a.shape[1] != 3:
                raise CLDataError(f'{name} must have shape (N, 3), got {a.shape}')
        if len(p) != len(o):
            raise CLDataError(f'{len(p)} positions but {len(o)} tool axes')
        if len(p) < MIN_POINTS:
            raise CLDataError(f'{len(p)} points, need at least {MIN_POINTS}')
        for name, a in (('position', p), ('tool axis', o)):
            bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
            if len(bad):
                raise CLDataError(f'point {bad[0]}: {name} is not finite (NaN or inf)', int(bad[0]))
        bad = np.flatnonzero((np.abs(p) > HUGE).any(axis=1))
        if len(bad):
            raise CLDataError(f'point {bad[0]}: position {p[bad[0]].tolist()} m has a coordinate beyond +-{HUGE:g} m, '
                              f'no distance can be taken of it', int(bad[0]))
        huge = np.abs(o).max(axis=1) > HUGE      # their squares would overflow the norm: scaled first
        o[huge] /= np.abs(o[huge]).max(axis=1)[:, None]
        norm = np.linalg.norm(o, axis=1)
        bad = np.flatnonzero(norm < MIN_AXIS_NORM)
        if len(bad):
            raise CLDataError(f'point {bad[0]}: zero-length tool axis', int(bad[0]))
        bad = closer_than(p, MIN_SPACING)
        if bad is not None:
            raise CLDataError(f'point {bad + 1} repeats point {bad}: {spacing_text(p, bad, MIN_SPACING)}', bad + 1)
        o = o / norm[:, None]
        p.setflags(write=False)
        o.setflags(write=False)
        object.__setattr__(self, 'positions', p)
        object.__setattr__(self, 'axes', o)

    def __len__(self) -> int:
        return len(self.positions)

    def max_tilt(self) -> float:
        """Largest angle (rad) between a tool axis and the workpiece +z axis."""
        return float(np.max(np.arccos(np.clip(self.axes[:, 2], -1.0, 1.0))))


def closer_than(positions: np.ndarray, spacing: float) -> int | None:
    """The first i whose tool tips i and i + 1 (positions (N, 3), m) are closer than
    `spacing` (m), or None."""
    bad = np.flatnonzero(np.linalg.norm(np.diff(positions, axis=0), axis=1) < spacing)
    return int(bad[0]) if len(bad) else None


def spacing_text(positions: np.ndarray, i: int, spacing: float) -> str:
    """'points 4 and 5 are 1e-12 m apart (need >= 1e-09 m)'."""
    gap = float(np.linalg.norm(positions[i + 1] - positions[i]))
    return f'points {i} and {i + 1} are {gap:.3g} m apart (need >= {spacing:.3g} m)'


def from_arrays(positions, axes) -> CLData:
    """CL data from arrays (N, 3) of tool tips (m) and tool axes (any length > 0)."""
    return CLData(np.asarray(positions, dtype=float), np.asarray(axes, dtype=float))


def axes_from_quaternions(q_xyzw) -> np.ndarray:
    """The z-axis (third column of the rotation matrix) of each quaternion (x, y, z, w),
    shape (N, 4) -> (N, 3): the tool axis of a pose whose z-axis is the tool axis. Each
    quaternion must be finite and unit within QUATERNION_TOLERANCE (then it is normalized);
    otherwise a CLDataError naming the pose (its index) and the norm."""
    q = np.asarray(q_xyzw, dtype=float)
    if q.ndim != 2 or q.shape[1] != 4:
        raise ValueError(f'quaternions must have shape (N, 4), got {q.shape}')
    bad = np.flatnonzero(~np.isfinite(q).all(axis=1))
    if len(bad):
        raise CLDataError(f'pose {bad[0]}: orientation quaternion is not finite (NaN or inf)', int(bad[0]))
    with np.errstate(over='ignore'):             # a norm beyond the float range is inf: refused below
        n = np.linalg.norm(q, axis=1)
        bad = np.flatnonzero(~(np.abs(n * n - 1.0) < QUATERNION_TOLERANCE))
    if len(bad):
        i = int(bad[0])
        what = 'zero length' if n[i] < MIN_AXIS_NORM else f'norm {n[i]:.6g}'
        raise CLDataError(f'pose {i}: orientation quaternion has {what}, not unit (|x² + y² + z² + w² - 1| '
                          f'must be below {QUATERNION_TOLERANCE:g})', i)
    x, y, z, w = (q / n[:, None]).T
    return np.column_stack((2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)))


# ---------------------------------------------------------------- CSV

def read_csv(path) -> CLData:
    """Read CL data from CSV: a header naming the columns px,py,pz,oi,oj,ok (any order),
    then one point per line, SI units (m). Blank lines and lines starting with '#' are
    skipped. Every problem is a one-line ValueError '<file>: line N: <problem>'."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ValueError(f'{path}: cannot read: {e.strerror}') from None
    rows, lines = [], []
    header = None
    for n, fields in enumerate(csv.reader(text.splitlines()), start=1):
        if not fields or not ''.join(fields).strip() or fields[0].lstrip().startswith('#'):
            continue
        fields = [f.strip() for f in fields]
        if header is None:
            names = [f.lower() for f in fields]
            missing = [c for c in COLUMNS if c not in names]
            unknown = [f for f in names if f not in COLUMNS]
            if missing:
                raise ValueError(f'{path}: line {n}: missing column(s) {",".join(missing)} '
                                 f'(header must name {",".join(COLUMNS)})')
            if unknown or len(names) != len(COLUMNS):
                raise ValueError(f'{path}: line {n}: unknown or repeated column(s) in header: '
                                 f'{",".join(fields)}')
            header = [names.index(c) for c in COLUMNS]
            continue
        if len(fields) != len(COLUMNS):
            raise ValueError(f'{path}: line {n}: {len(fields)} values, expected {len(COLUMNS)}')
        try:
            values = [float(fields[i]) for i in header]
        except ValueError:
            bad = next(f for f in fields if not _is_float(f))
            raise ValueError(f'{path}: line {n}: not a number: {bad!r}') from None
        rows.append(values)
        lines.append(n)
    if header is None:
        raise ValueError(f'{path}: no header line (expected {",".join(COLUMNS)})')
    if len(rows) < MIN_POINTS:
        raise ValueError(f'{path}: {len(rows)} data rows, need at least {MIN_POINTS}')
    data = np.array(rows)
    try:
        return CLData(data[:, :3], data[:, 3:])
    except CLDataError as e:
        where = f'line {lines[e.index]}: ' if e.index is not None else ''
        raise ValueError(f'{path}: {where}{e}') from None


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def write_csv(path, cl: CLData) -> None:
    """Write CL data in the format of `read_csv` (shortest round-trip floats: exact)."""
    with open(path, 'w', newline='') as f:
        f.write(','.join(COLUMNS) + '\n')
        for p, o in zip(cl.positions, cl.axes):
            f.write(','.join(repr(float(v)) for v in (*p, *o)) + '\n')


# ---------------------------------------------------------------- built-in paths

def _tilted(direction_xy: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """Unit axes tilted by `tilt` (rad) from +z towards the x-y vector `direction_xy` (N, 2,
    unit or zero)."""
    return np.column_stack((np.sin(tilt) * direction_xy[:, 0], np.sin(tilt) * direction_xy[:, 1],
                            np.cos(tilt)))


def circle_xy(radius: float = 4e-3, points: int = 361) -> CLData:
    """Thesis (seed 000) section 3.4: "a circle of radius 4 [mm] on the x-y plane", vertical
    tool axis. One closed revolution (last point = first) about the origin, z = 0, starting
    on +x, counter-clockwise.
    # assumed: centre at the origin, z = 0, start angle 0, 361 points (1 deg spacing; the
    seed gives no sampling)."""
    if not radius > 0 or not math.isfinite(radius):
        raise ValueError(f'circle radius must be a positive finite number of m, got {radius}')
    if points < MIN_POINTS:
        raise ValueError(f'circle needs at least {MIN_POINTS} points, got {points}')
    t = np.linspace(0.0, 2 * np.pi, points)
    p = np.column_stack((radius * np.cos(t), radius * np.sin(t), np.zeros(points)))
    p[-1] = p[0]  # exactly closed
    return CLData(p, np.tile([0.0, 0.0, 1.0], (points, 1)))


def spiral(r_start: float = 1e-3, r_end: float = 20e-3, turns: float = 5.0, depth: float = 2e-3,
           points_per_turn: int = 72) -> CLData:
    """Thesis (seed 000) Fig. 6.1 / section 6.2 "Spiral toolpath", used to validate trajectory
    generation (redundancy resolution within strokes, velocity/acceleration/jerk limits) and,
    in section 6.4, geometric error compensation. The thesis gives the figure only, no
    dimensions.
    # assumed: an Archimedean spiral outward from r_start = 1 mm to r_end = 20 mm in 5 turns
    (within the +-50 mm x/y strokes of the 100 mm micromill, seed-notes.md), descending
    linearly by 2 mm in z (conical, so z_c moves too), 72 points per turn. Tool axis tilted
    towards the outside, the tilt growing linearly with the radius to 0.25 deg at r_end
    (within the +-0.5 deg a_f/b_f strokes), so the table's tilt axes take part."""
    n = int(round(turns * points_per_turn)) + 1
    t = np.linspace(0.0, 1.0, n)
    theta = 2 * np.pi * turns * t
    r = r_start + (r_end - r_start) * t
    p = np.column_stack((r * np.cos(theta), r * np.sin(theta), -depth * t))
    direction = np.column_stack((np.cos(theta), np.sin(theta)))
    return CLData(p, _tilted(direction, GENERATED_TILT * r / r_end))


def helix(radius: float = 5e-3, pitch: float = 1e-3, turns: float = 3.0,
          points_per_turn: int = 72) -> CLData:
    """CIRP paper (seed 002) section 5 / Fig. 2: the machine was tested on "a spatial helical
    path" with position and orientation commands (the tool orientation changes: the rotary
    table's a/b/c axes move; a C-axis "direction change occurs" at 2.3 s). No dimensions
    are printed (the caption of Fig. 2 is misplaced under "Figure 4" in the text).
    # assumed: radius 5 mm, pitch 1 mm descending (-z), 3 turns, 72 points per turn; the tool
    axis tilts towards the helix axis by 0.25 deg times cos(theta / 2), so the tilt
    direction turns with the path and reverses once per two turns (a direction change of
    the c-like rotation), while staying within the +-0.5 deg a_f/b_f strokes."""
    n = int(round(turns * points_per_turn)) + 1
    theta = np.linspace(0.0, 2 * np.pi * turns, n)
    p = np.column_stack((radius * np.cos(theta), radius * np.sin(theta),
                         -pitch * theta / (2 * np.pi)))
    inward = -np.column_stack((np.cos(theta), np.sin(theta)))
    return CLData(p, _tilted(inward, GENERATED_TILT * np.cos(theta / 2)))


def sinusoidal_surface(size: float = 10e-3, peak_to_peak: float = 500e-6,
                       stepover: float = 10e-6, wavelength: float = 5e-3,
                       point_spacing: float = 0.25e-3) -> CLData:
    """Thesis (seed 000) section 6.2 / Fig. 6.6: the sinusoidal freeform surface, "peak to
    peak amplitude of 500 microns and a working surface area of 10 [mm] x 10 [mm]", cut with
    a 1/64" (397 um) ball end mill, "a constant tilt of 0.15 degrees", "zig-zag toolpath"
    with "a step over of 10 [um]" (finishing pass).

    Surface z = (peak_to_peak / 2) sin(2 pi x / L) sin(2 pi y / L) over [0, size]^2. The tool
    tip is placed so the ball touches the surface: tip = S + r n - r O (S the surface point,
    n its unit normal, r the ball radius, O the tool axis). Rows run along x, alternating
    direction, joined by half circles of diameter `stepover` (in the x-y plane, just outside
    the area, z continuous). Along a row the points are cosine-spaced (denser near the ends)
    so the spacing shrinks towards the tight turn.
    # assumed: wavelength L = 5 mm (not stated, seed-notes.md), the surface formula (a
    product of sines), tilt direction towards +x (only "constant tilt" is stated), about
    0.25 mm mean point spacing along a row, 5 points on each turn. With the default
    stepover there are 1001 rows (~46k points): pass a larger stepover for a short path."""
    radius = 0.397e-3 / 2  # m, thesis section 6.2: 1/64" (397 um) ball end mill
    tilt = math.radians(0.15)  # thesis section 6.2: constant tilt 0.15 deg
    amplitude = peak_to_peak / 2
    k = 2 * np.pi / wavelength
    axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])

    def tip(x, y):
        z = amplitude * np.sin(k * x) * np.sin(k * y)
        zx = amplitude * k * np.cos(k * x) * np.sin(k * y)
        zy = amplitude * k * np.sin(k * x) * np.cos(k * y)
        normal = np.column_stack((-zx, -zy, np.ones_like(z)))
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        return np.column_stack((x, y, z)) + radius * normal - radius * axis

    rows = int(round(size / stepover)) + 1
    per_row = max(int(round(size / point_spacing)) + 1, MIN_POINTS)
    x_row = size * 0.5 * (1 - np.cos(np.linspace(0.0, np.pi, per_row)))
    turn = np.linspace(0.0, np.pi, 7)[1:-1]  # 5 interior points of each half circle
    pieces = []
    for i in range(rows):
        y0 = i * stepover
        x = x_row if i % 2 == 0 else x_row[::-1]
        pieces.append(tip(x, np.full(per_row, y0)))
        if i + 1 < rows:
            side = 1.0 if i % 2 == 0 else -1.0  # turn beyond x = size, or before x = 0
            xc = size if side > 0 else 0.0
            pieces.append(tip(xc + side * stepover / 2 * np.sin(turn),
                              y0 + stepover / 2 * (1 - np.cos(turn))))
    p = np.vstack(pieces)
    return CLData(p, np.tile(axis, (len(p), 1)))


BUILTIN: dict[str, Callable[[], CLData]] = {
    'spiral': spiral,
    'helix': helix,
    'circle_xy': circle_xy,
    'sinusoidal_surface': sinusoidal_surface,
}


def builtin(name: str) -> CLData:
    """A built-in toolpath by name (see BUILTIN), with its default dimensions."""
    try:
        return BUILTIN[name]()
    except KeyError:
        raise ValueError(f'unknown toolpath {name!r} (known: {", ".join(BUILTIN)})') from None
