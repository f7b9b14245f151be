"""Spindle-slaved freeform commands for a fast tool servo (Ding thesis, seed
003_edeaa855566124b7, Ch. 8): the spindle turns at a constant speed, the radial slide feeds
towards the centre at a constant feed per revolution, and the fast axis follows the height
of a freeform surface under the tool, computed every control step from the spindle angle and
the radial position (section 8.3; the thesis's DSP evaluates the surface equation each servo
cycle, "no interpolation is required", section 8.5.3).

    theta(t) = theta_0 + Omega t,   r(t) = r_0 - f Omega t / (2 pi),
    w(t) = h(r cos theta, r sin theta)

Surfaces (height h in m at workpiece coordinates x, y in m):
* :class:`SinusoidalGrid` — section 8.5.4, Table 8-5: A_x sin(2 pi x/lambda_x) + A_y sin(2 pi y/lambda_y);
* :class:`BeamIntegrator` — section 8.5.3, Table 8-4 and its script: a square array (pitch L)
  of spherical cups of radius R, h = R - sqrt(R^2 - rho^2) in each cell's local coordinates;
* :class:`MicroLensArray` — section 8.5.2, Table 8-3: the micro-lenslet ring, the fast axis a
  sine in the spindle angle, h = A sin(n atan2(y, x)), n lenslets per revolution;
* :class:`SurfaceTable` — any surface as a table of heights on a regular x-y grid (a CSV
  file: x, y, height per row), bilinear between the nodes.

The commands are computed from the *commanded* spindle angle and radius (the reference the
C and X servos track), where the thesis reads its encoders: in a lock-step machine both are
known at the same step, and they differ by C's and X's tracking errors. The fast axis's
velocity and acceleration are the central differences of its sampled positions (second
order; one-sided at the ends).

:func:`freeform_program` makes it a motion a machine can run from where it stands: a
time-optimal jerk-limited entry (Ruckig) that brings the spindle up to speed and the slide to
its radius and feed with the fast axis at rest at its home; a lead-in over which the fast axis
lands on the surface (still slaved to the spindle angle and radius, its height faded in); the
cut; the lead-out (faded out); a time-optimal stop. The fast axis stays at its home through
the slow axes' entry and stop (to Ruckig's ~1e-21 m residual), so its stroke holds whatever
the spindle needs to get up to speed; what
the trajectory node runs for a freeform goal. It starts from wherever the machine stands: a
second cut from where the first stopped (the spindle a few turns on, the slide inside its
start radius) either continues at the spindle's angle (``start_angle`` = its angle) or turns
back to the angle asked for; the spindle's range is that of any unlimited axis
(axis_limits.unlimited_range). The entry ends where Ruckig's precision lets it (~1e-12 of
the target away from home) and the residual is spread over it (_land_on), so the junction
with the cut carries no step. :func:`surface_named`
reads a surface by name (``sinusoidal_grid``, ``beam_integrator``, ``micro_lens_array``: the
thesis's) or CSV path.

:func:`freeform_reference` returns a :class:`FreeformResult` (status, reason, reference):
a surface that leaves the fast axis's stroke, a feed that crosses the spindle centre, a
non-finite height or limits exceeded are refused with the reason, nothing clamped. Limits:
a surface with a kink (the beam integrator's cell borders) has a velocity jump there that no
finite acceleration limit allows; ``check_limits=False`` then runs it as the thesis did, and
the result still carries each axis's peak velocity and acceleration.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

import numpy as np

from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.reference import Reference
from trajectory.axis_limits import TOLERANCE, amount
from trajectory import moves
from trajectory.moves import AxisState, stroke_violation


@dataclass(frozen=True)
class SinusoidalGrid:
    """Ding section 8.5.4, Table 8-5 (defaults): +-5 um amplitudes, 1 mm wavelengths."""
    amplitude_x: float = 5e-6
    amplitude_y: float = 5e-6
    wavelength_x: float = 1e-3
    wavelength_y: float = 1e-3

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return (self.amplitude_x * np.sin(2 * np.pi * x / self.wavelength_x)
                + self.amplitude_y * np.sin(2 * np.pi * y / self.wavelength_y))


@dataclass(frozen=True)
class BeamIntegrator:
    """Ding section 8.5.3, Table 8-4 (defaults): sphere radius R = 100 mm, pitch L = 2 mm
    (10 um sag at the cell corners, 5 um at the edges: seed-notes.md names the 10-vs-5 um
    depth inconsistency of the text)."""
    radius: float = 0.1
    pitch: float = 2e-3

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        pitch = self.pitch
        local_x = x - np.floor(x / pitch) * pitch - pitch / 2
        local_y = y - np.floor(y / pitch) * pitch - pitch / 2
        return self.radius - np.sqrt(self.radius ** 2 - (local_x ** 2 + local_y ** 2))


@dataclass(frozen=True)
class MicroLensArray:
    """Ding section 8.5.2, Table 8-3 (defaults): the fast axis moves as a sine of the spindle
    angle, `per_revolution` periods per turn, and the tool cuts the material at the far end of
    each stroke (depth of cut half the amplitude), one lenslet per period. 100 Hz at the 16 rpm
    of Table 8-3 is 375 per revolution; the amplitude is the text's nominal 5 um (Table 8-3
    prints 10 um: seed-notes.md). The height is the commanded motion; the surface cut is its
    envelope above the depth of cut."""
    amplitude: float = 5e-6
    per_revolution: int = 375

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.amplitude * np.sin(self.per_revolution * np.arctan2(y, x))


@dataclass(frozen=True)
class SurfaceTable:
    """Heights on a regular grid: `x` (n,), `y` (m,) increasing, `height` (n, m); bilinear in
    between, refused (non-finite) outside the grid."""
    x: np.ndarray
    y: np.ndarray
    height_grid: np.ndarray = field(repr=False)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        gx, gy, h = self.x, self.y, self.height_grid
        inside = (x >= gx[0]) & (x <= gx[-1]) & (y >= gy[0]) & (y <= gy[-1])
        i = np.clip(np.searchsorted(gx, x, side='right') - 1, 0, len(gx) - 2)
        j = np.clip(np.searchsorted(gy, y, side='right') - 1, 0, len(gy) - 2)
        tx = (x - gx[i]) / (gx[i + 1] - gx[i])
        ty = (y - gy[j]) / (gy[j + 1] - gy[j])
        value = ((1 - tx) * (1 - ty) * h[i, j] + tx * (1 - ty) * h[i + 1, j]
                 + (1 - tx) * ty * h[i, j + 1] + tx * ty * h[i + 1, j + 1])
        return np.where(inside, value, np.nan)


class SurfaceTableError(ValueError):
    """A surface table file that cannot be read; the message names the file and the row."""


def read_surface_table(path) -> SurfaceTable:
    """A CSV of rows x, y, height (m; an optional header line), every (x, y) of a regular
    grid exactly once, in any order."""
    path = Path(path)
    rows = []
    try:
        with path.open(newline='') as f:
            for n, row in enumerate(csv.reader(f), start=1):
                if not row or (n == 1 and not _numbers(row)):
                    continue
                if len(row) != 3 or not _numbers(row):
                    raise SurfaceTableError(f'{path}: row {n}: need three numbers x, y, height (m), got {row!r}')
                rows.append([float(v) for v in row])
    except OSError as exc:
        raise SurfaceTableError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise SurfaceTableError(f'{path}: not a CSV surface table: {exc}') from None
    data = np.array(rows, dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(data)):
        raise SurfaceTableError(f'{path}: row {int(np.flatnonzero(~np.isfinite(data).all(axis=1))[0]) + 1}: '
                                'values must be finite')
    xs, ys = np.unique(data[:, 0]), np.unique(data[:, 1])
    if len(xs) < 2 or len(ys) < 2 or len(data) != len(xs) * len(ys):
        raise SurfaceTableError(f'{path}: {len(data)} rows do not form a regular grid of at least 2 x 2 '
                                f'({len(xs)} distinct x, {len(ys)} distinct y)')
    grid = np.full((len(xs), len(ys)), np.nan)
    grid[np.searchsorted(xs, data[:, 0]), np.searchsorted(ys, data[:, 1])] = data[:, 2]
    if np.isnan(grid).any():
        raise SurfaceTableError(f'{path}: an (x, y) appears twice, so another is missing: not a regular grid')
    return SurfaceTable(xs, ys, grid)


def _numbers(row) -> bool:
    try:
        [float(v) for v in row]
        return True
    except ValueError:
        return False


def axis_sine(machine: MachineConfig, axis: str, amplitude: float, frequency: float, duration: float) -> Reference:
    """Every axis at its home, `axis` home + A sin(2 pi f t) with its exact velocity and
    acceleration, for `duration` s (a sine starts at full speed): the FTS's sinusoidal motions
    (Ding Table 8-3's lenslet cut, the 20 Hz motions of section 8.5.4)."""
    steps = int(round(duration / machine.control_period)) + 1
    time = np.arange(steps) * machine.control_period
    position = np.tile(np.asarray(machine.home, dtype=float), (steps, 1))
    velocity, acceleration = np.zeros_like(position), np.zeros_like(position)
    j, w = machine.axis_names.index(axis), 2 * math.pi * frequency
    position[:, j] += amplitude * np.sin(w * time)
    velocity[:, j] = amplitude * w * np.cos(w * time)
    acceleration[:, j] = -amplitude * w * w * np.sin(w * time)
    return Reference(machine.axis_names, machine.control_period, position, velocity, acceleration)


@dataclass(frozen=True)
class Turning:
    """The cut: spindle speed Omega (rad/s, > 0), feed per revolution (m/rev, >= 0, towards
    the centre), start radius r_0 and spindle angle theta_0, duration (s)."""
    spindle_speed: float
    feed_per_rev: float
    start_radius: float
    duration: float
    start_angle: float = 0.0


class FreeformStatus(StrEnum):
    OK = 'ok'
    INVALID_INPUT = 'invalid_input'        # the turning parameters or the machine's axes
    OUT_OF_STROKE = 'out_of_stroke'        # the surface needs the fast axis (or the slide) beyond its stroke
    EXCEEDS_LIMITS = 'exceeds_limits'      # a velocity or acceleration beyond an axis's limit


@dataclass(frozen=True)
class FreeformResult:
    status: FreeformStatus
    reason: str = ''
    reference: Reference | None = None
    peaks: dict = field(default_factory=dict)   # axis -> (max |velocity|, max |acceleration|)
    cut: tuple[int, int] | None = None          # freeform_program: rows [first, end) of the cut

    @property
    def ok(self) -> bool:
        return self.status is FreeformStatus.OK


def freeform_reference(machine: MachineConfig, surface, turning: Turning, spindle: str = 'c',
                       radial: str = 'x', fast: str = 'w', check_limits: bool = True,
                       lead: float = 0.0) -> FreeformResult:
    """The spindle-slaved reference of the module doc: every other axis at its home. With
    `lead` > 0 s the spindle and the slide run `lead` longer at each end (the same formulas:
    the cut's rows are the same numbers) while the fast axis lands on the surface from its home
    and lifts off it again, its height times a septic smoothstep (position to jerk continuous)."""
    bad = FreeformStatus.INVALID_INPUT
    for role, name in (('spindle', spindle), ('radial', radial), ('fast', fast)):
        if name not in machine.axis_names:
            return FreeformResult(bad, f'{machine.name} has no {role} axis {name!r} (axes: {", ".join(machine.axis_names)})')
    t = turning
    numbers = (t.spindle_speed, t.feed_per_rev, t.start_radius, t.duration, t.start_angle)
    if not all(math.isfinite(v) for v in numbers):
        return FreeformResult(bad, f'turning parameters must be finite, got {t}')
    if t.spindle_speed <= 0 or t.duration <= 0 or t.feed_per_rev < 0:
        return FreeformResult(bad, 'spindle speed and duration must be > 0 and the feed >= 0, got '
                                   f'{t.spindle_speed:g} rad/s, {t.duration:g} s, {t.feed_per_rev:g} m/rev')
    period = machine.control_period
    if not (math.isfinite(lead) and lead >= 0):
        return FreeformResult(bad, f'lead must be >= 0 s, got {lead!r}')
    if (t.duration + 2 * lead) / period > moves.MAX_GOAL_STEPS:
        return FreeformResult(bad, f'duration {t.duration:g} s is beyond the '
                                   f'{moves.MAX_GOAL_STEPS * period:g} s a cut may last ({moves.MAX_GOAL_STEPS} control '
                                   'steps: it is computed in memory)')
    steps = int(round(t.duration / period)) + 1
    if steps < 3:
        return FreeformResult(bad, f'duration {t.duration:g} s is shorter than two control periods')
    led = int(round(lead / period))
    time = np.arange(-led, steps + led) * period
    radial_speed = t.feed_per_rev * t.spindle_speed / (2 * math.pi)
    end_radius = t.start_radius - radial_speed * time[-1]
    if end_radius < 0:
        return FreeformResult(bad, f'the feed crosses the spindle centre: radius {amount(end_radius, "m")} '
                                   f'below 0 at the end ({t.feed_per_rev:g} m/rev for {t.duration:g} s from '
                                   f'{amount(t.start_radius, "m")})')
    theta = t.start_angle + t.spindle_speed * time
    radius = t.start_radius - radial_speed * time
    height = np.asarray(surface.height(radius * np.cos(theta), radius * np.sin(theta)), dtype=float)
    if not np.all(np.isfinite(height)):
        k = int(np.flatnonzero(~np.isfinite(height))[0])
        return FreeformResult(bad, f'the surface has no finite height at x = {radius[k] * math.cos(theta[k]):.6g} m, '
                                   f'y = {radius[k] * math.sin(theta[k]):.6g} m (t = {time[k]:.6g} s)')
    names = machine.axis_names
    position = np.tile(np.asarray(machine.home, dtype=float), (len(time), 1))
    velocity, acceleration = np.zeros_like(position), np.zeros_like(position)
    ic, ir, iw = (names.index(a) for a in (spindle, radial, fast))
    position[:, ic], velocity[:, ic] = theta, t.spindle_speed
    position[:, ir], velocity[:, ir] = radius, -radial_speed
    position[:, iw] = position[0, iw] + height * _landing(len(time), led)
    velocity[:, iw] = np.gradient(position[:, iw], period, edge_order=2)
    acceleration[:, iw] = np.gradient(velocity[:, iw], period, edge_order=2)
    reference = Reference(names, period, position, velocity, acceleration)
    peaks = {names[i]: (float(np.abs(velocity[:, i]).max()), float(np.abs(acceleration[:, i]).max()))
             for i in (ic, ir, iw)}
    problem = stroke_violation(machine, reference)
    if problem:
        return FreeformResult(FreeformStatus.OUT_OF_STROKE, problem, None, peaks)
    if check_limits:
        for i in (ic, ir, iw):
            axis = machine.axes[i]
            for what, peak, limit, unit in (('velocity', peaks[names[i]][0], axis.limits.velocity, f'{axis.unit}/s'),
                                            ('acceleration', peaks[names[i]][1], axis.limits.acceleration,
                                             f'{axis.unit}/s^2')):
                if peak > limit * TOLERANCE:
                    return FreeformResult(FreeformStatus.EXCEEDS_LIMITS,
                                          f'{axis.name} needs a peak {what} of {peak:.4g} {unit}, beyond its limit '
                                          f'{limit:g} {unit}', None, peaks)
    return FreeformResult(FreeformStatus.OK, '', reference, peaks)


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The septic smoothstep s = 35x^4 - 84x^5 + 70x^6 - 20x^7 on [0, 1] and its first two
    derivatives in x: 0 to 1 with zero slope up to the third derivative at both ends."""
    s = x ** 4 * (35 - 84 * x + 70 * x * x - 20 * x ** 3)
    ds = 140 * x ** 3 * (1 - x) ** 3
    dds = 420 * x ** 2 * (1 - x) ** 2 * (1 - 2 * x)
    return s, ds, dds


def _landing(n: int, led: int) -> np.ndarray:
    """1 over n rows but the first and last `led`, which rise from 0 and fall to 0 by the
    septic smoothstep (_smoothstep)."""
    weight = np.ones(n)
    if led:
        ramp = _smoothstep(np.arange(led) / led)[0]
        weight[:led], weight[n - led:] = ramp, ramp[::-1]
    return weight


def _land_on(machine: MachineConfig, entry: Reference, target: Reference) -> None:
    """Make the entry end exactly on the cut's first row. Ruckig ends within its own
    precision of a target (~1e-12 m or rad from a start away from home), not on it: a step of
    2e-12 m between two rows 5 µs apart reads up to 3.2e4 m/s³ of jerk (2 x step / T³). The residual is spread over
    the whole entry by the septic smoothstep (its jerk: at most the residual x 52.5 /
    duration³, 4e-9 m/s³ for 2e-12 m over a 0.3 s entry), velocity and acceleration with it;
    the last row is then the cut's own. ValueError for a residual beyond RUCKIG_PRECISION."""
    n = len(entry)
    residual = target.position[0] - entry.position[-1]
    off = np.abs(residual) > RUCKIG_PRECISION * np.maximum(1.0, np.abs(target.position[0]))
    if off.any():                            # not Ruckig's precision: something else is wrong
        k = int(np.argmax(off))
        axis = machine.axes[k]
        raise ValueError(f'the entry ends {amount(residual[k], axis.unit)} away from the cut on {axis.name}, '
                         f"beyond Ruckig's precision ({RUCKIG_PRECISION:g} x max(1, |position|))")
    duration = (n - 1) * entry.period
    if n > 1 and residual.any():
        s, ds, dds = _smoothstep(np.arange(n) / (n - 1))
        entry.position += s[:, None] * residual
        entry.velocity += ds[:, None] * (residual / duration)
        entry.acceleration += dds[:, None] * (residual / duration ** 2)
    for name in ('position', 'velocity', 'acceleration'):
        getattr(entry, name)[-1] = getattr(target, name)[0]


SURFACES = {'sinusoidal_grid': SinusoidalGrid, 'beam_integrator': BeamIntegrator,      # the thesis's, by name
            'micro_lens_array': MicroLensArray}
LEAD = 0.02     # s, assumed: the fast axis lands on the surface and lifts off over 20 ms (module doc)
# Ruckig reaches a target within ~1e-12 (relative to max(1, |position|)) from a start away
# from home (measured: 2e-12 m on x from 0.994 mm); assumed: 1e-9 bounds it with room.
RUCKIG_PRECISION = 1e-9
JUNCTION_SCALE = 0.98   # the entry and stop at 98 % of the limits: sampled across their junctions with the
                        # cut (at speed) the jerk would otherwise read up to ~1 % over (test_freeform.py)


def surface_named(spec: str):
    """A surface by name (SURFACES) or by the path of a CSV surface table; ValueError with
    the reason."""
    if spec in SURFACES:
        return SURFACES[spec]()
    if not spec.lower().endswith('.csv'):
        raise ValueError(f'surface {spec!r}: a name ({", ".join(SURFACES)}) or a .csv surface table')
    return read_surface_table(spec)


def freeform_program(machine: MachineConfig, surface, turning: Turning, start: AxisState,
                     spindle: str = 'c', radial: str = 'x', fast: str = 'w', check_limits: bool = True,
                     lead: float = LEAD) -> FreeformResult:
    """The cut of :func:`freeform_reference` as a whole motion from `start` (module doc):
    an entry that brings the spindle and the slide up to the cut's speeds (the fast axis home,
    at rest), the lead-in, the cut, the lead-out, a stop. `cut` in the result: the rows of the
    cut (those of freeform_reference without a lead)."""
    cut = freeform_reference(machine, surface, turning, spindle, radial, fast, check_limits, lead)
    if not cut.ok:
        return cut
    ref = cut.reference
    led = int(round(lead / machine.control_period))
    into, out_of = (AxisState(*(tuple(float(v) for v in getattr(ref, f)[row]) for f in ('position', 'velocity',
                                                                                      'acceleration')))
                    for row in (0, -1))
    try:
        entry = moves.move_to_state(machine, into, start, JUNCTION_SCALE)
        stop = moves.smooth_stop(machine, out_of, JUNCTION_SCALE)
        _land_on(machine, entry, ref)
    except ValueError as exc:
        return FreeformResult(FreeformStatus.EXCEEDS_LIMITS, f'no entry into or stop out of the cut: {exc}', None,
                              cut.peaks)
    whole = moves.concatenate([entry, ref, stop])
    if len(whole) > 2 * moves.MAX_GOAL_STEPS:
        return FreeformResult(FreeformStatus.INVALID_INPUT, f'entry, cut and stop take {len(whole)} control steps, '
                                                            f'beyond {2 * moves.MAX_GOAL_STEPS}', None, cut.peaks)
    first = len(entry) - 1 + led
    return FreeformResult(FreeformStatus.OK, '', whole, cut.peaks, (first, first + len(ref) - 2 * led))
