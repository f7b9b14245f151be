"""G-code in (issue [7/8], part 1): a part program's text, the RS-274/NGC subset below, read
into motions (:func:`parse`) and cut into the tool paths the planner takes (:func:`pieces`).

Why a parser of our own: of the G-code parsers on the package index, gcodeparser (0.3.0,
2025) only splits a line into words (no modal state, no arcs, no units) and installs a
top-level package named ``test``; pygcode (0.2.1, 2017) is unmaintained and GPL-3.0. The
subset is small; its meaning follows NIST RS274/NGC version 3 (Kramer, Proctor, Messina,
NISTIR 6556, 2000) as LinuxCNC reads it.

The subset (anything else is refused, ``file:line: reason``, and nothing is planned):

* motion, modal: ``G0`` rapid, ``G1`` linear feed, ``G2`` / ``G3`` clockwise /
  counter-clockwise arc seen from the plane's positive normal, helical when the normal
  axis moves too; centre by ``I J K`` (offsets from the start point, always incremental:
  LinuxCNC's ``G91.1``) or by ``R`` (negative R: the arc longer than a half turn); a full
  circle needs ``I J K``. The end's distance to the centre may differ from the start's by
  at most ``ARC_RADIUS_TOLERANCE``; the radius then changes linearly along the arc;
* arc planes ``G17`` (XY, the default), ``G18`` (ZX), ``G19`` (YZ);
* units ``G20`` inch, ``G21`` mm (the default); distances ``G90`` absolute (the default),
  ``G91`` incremental (rotary words too);
* feed ``G94`` units per minute (the default) with a modal ``F``; ``G93`` inverse time:
  every feed block has its own ``F`` and takes 1/F minutes;
* ``A B C``: rotary axis positions in degrees, giving the tool's orientation through the
  machine's kinematics (:func:`tool_axis_of`; A0 B0 C0 is the machine's home orientation,
  on trt_5axis the workpiece frame's +y); X Y Z are the tool tip in the machine's workpiece
  frame (as with a controller's tool-centre-point mode on);
* ``S`` and ``M3 M4 M5`` (spindle): read and ignored, with a note (the simulated machines
  have no spindle); ``G40 G49 G54 G61 G80 G91.1``: the modes already in force (no cutter
  or length compensation, the first work offset, exact stop, no canned cycle, incremental
  arc centres): accepted, no effect;
* ``M0`` program stop (a pause after the block before it), ``M2`` / ``M30`` program end
  (the lines after it are not read); ``N`` line numbers, ``( ... )`` and ``;`` comments,
  ``%`` delimiter lines (a ``%`` after the first block, or the second one, ends the program).

Also refused: two codes of one modal group in a block (``G20 G21``), a coordinate, centre
offset or radius beyond ``MAX_COORDINATE``. A move shorter than ``MIN_MOVE`` is no motion,
with a note, as is a block that ends where it starts.

From motions to tool paths: the planner plans a path from rest to rest, so a program
becomes pieces, each one path (an exact stop between pieces, as ``G61``): a rapid block is
a piece of its own, planned at ``RAPID_FEED`` (above every axis's speed, so the axes' own
limits bound it, as a controller's rapids); consecutive feed blocks with the same feed whose
tangents join within ``JOIN_ANGLE`` form one piece; a corner, a change of feed, an ``M0``
or a rapid end it. Plain Python and numpy, no rclpy.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import Callable

import numpy as np

from machine_ctrl.model.numeric import MAX_COORDINATE
from trajectory import toolpath

MM, INCH = 1e-3, 25.4e-3                 # m per program unit
# assumed: 2 µm, LinuxCNC's tolerance for an arc end off the circle of its start (mm
# programs: 0.002 mm); a larger difference is a wrong end point, not a spiral.
ARC_RADIUS_TOLERANCE = 2e-6              # m
# assumed: arcs sampled so that the chord's sagitta is at most 0.1 µm (the quintic spline
# through the samples lies far closer to the arc than the chords), and every block's samples
# at most 0.1 mm apart (a short block's closer: it has at least MIN_SEGMENTS + 1).
CHORD_SAGITTA = 0.1e-6                   # m
MAX_SPACING = 0.1e-3                     # m
MIN_SEGMENTS = 5                         # a block's fewest samples - 1 (toolpath.MIN_POINTS = 6)
# a block shorter than this has no room for its samples (toolpath.MIN_SPACING apart): no motion
MIN_MOVE = MIN_SEGMENTS * toolpath.MIN_SPACING
# assumed: 0.1 deg. Two blocks whose tangents differ by more are a corner: the piece ends
# there (an exact stop). A smaller kink is smoothed by the spline through the samples by
# about spacing x angle / 8 <= 0.1 mm x 1.7e-3 / 8 = 0.02 µm.
JOIN_ANGLE = math.radians(0.1)
# assumed: 10 m/s, above every axis speed of the shipped machines (tested), so a rapid's
# only bound is the axes' limits (the planner's feed is a tool-tip speed limit).
RAPID_FEED = 10.0                        # m/s

PLANES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}      # (first, second, normal) axis index
# modal groups other than motion: at most one code of each in a block
MODAL_GROUPS = {17: 'plane', 18: 'plane', 19: 'plane', 20: 'units', 21: 'units', 90: 'distance', 91: 'distance',
                93: 'feed mode', 94: 'feed mode'}
IN_FORCE = (40.0, 49.0, 54.0, 61.0, 80.0, 91.1)             # G codes of modes already in force
ROTARY = 'ABC'
_WORD = re.compile(r'\s*([A-Za-z])\s*([+-]?(?:\d+\.?\d*|\.\d+))\s*')
_COMMENT = re.compile(r'\([^()]*\)')


class GcodeStatus(StrEnum):
    OK = 'ok'
    INVALID_INPUT = 'invalid_input'      # a word, code or geometry outside the subset (the reason names it)


class GcodeError(ValueError):
    """A refusal, with its line (1-based) in the program."""

    def __init__(self, line: int, reason: str):
        super().__init__(reason)
        self.line = line


@dataclass(frozen=True)
class Arc:
    """A circular (helical) arc: its centre (m), the plane's axis indices (first, second,
    normal), the swept angle (rad, positive counter-clockwise seen from +normal) and the
    radii at its start and end (m)."""
    centre: np.ndarray
    plane: tuple[int, int, int]
    sweep: float
    radius_start: float
    radius_end: float


@dataclass(frozen=True)
class Motion:
    """One motion block, its modes resolved: the tool tip from `start` to `end` (m, workpiece
    frame), the rotary words from `rotary_start` to `rotary_end` (rad, A B C; 0 where never
    programmed), straight or along `arc`; `feed` in m/s (None: a rapid); `line` in the
    program; `stop_after`: an M0 follows it."""
    line: int
    start: np.ndarray
    end: np.ndarray
    rotary_start: tuple[float, float, float]
    rotary_end: tuple[float, float, float]
    feed: float | None
    arc: Arc | None = None
    stop_after: bool = False

    @property
    def rapid(self) -> bool:
        return self.feed is None

    @property
    def length(self) -> float:
        """Tool-tip path length (m)."""
        if self.arc is None:
            return float(np.linalg.norm(self.end - self.start))
        a = self.arc
        planar = abs(a.sweep) * 0.5 * (a.radius_start + a.radius_end)
        return math.hypot(planar, float(self.end[a.plane[2]] - self.start[a.plane[2]]))

    def point(self, u: np.ndarray) -> np.ndarray:
        """Tool tips at the fractions `u` (0 = start, 1 = end) of the block, shape (len(u), 3)."""
        u = np.asarray(u, dtype=float)[:, None]
        if self.arc is None:
            return self.start + u * (self.end - self.start)
        a = self.arc
        i, j, k = a.plane
        angle0 = math.atan2(self.start[j] - a.centre[j], self.start[i] - a.centre[i])
        angle = angle0 + u[:, 0] * a.sweep
        radius = a.radius_start + u[:, 0] * (a.radius_end - a.radius_start)
        p = np.empty((len(u), 3))
        p[:, i] = a.centre[i] + radius * np.cos(angle)
        p[:, j] = a.centre[j] + radius * np.sin(angle)
        p[:, k] = self.start[k] + u[:, 0] * (self.end[k] - self.start[k])
        return p

    def tangent(self, u: float) -> np.ndarray:
        """Unit direction of motion at the fraction `u`."""
        h = 1e-7
        a, b = self.point(np.array([max(u - h, 0.0), min(u + h, 1.0)]))
        d = b - a
        return d / np.linalg.norm(d)

    def samples(self) -> np.ndarray:
        """Fractions u of the block's samples: 0 and 1 included, at most MAX_SPACING apart
        and, on an arc, with a chord sagitta of at most CHORD_SAGITTA."""
        n = max(MIN_SEGMENTS, math.ceil(self.length / MAX_SPACING))
        if self.arc is not None:
            radius = max(self.arc.radius_start, self.arc.radius_end)
            step = 2.0 * math.acos(max(1.0 - CHORD_SAGITTA / radius, -1.0))
            n = max(n, math.ceil(abs(self.arc.sweep) / step))
        return np.linspace(0.0, 1.0, n + 1)


@dataclass(frozen=True)
class Program:
    """A read program: its motions in order, the notes on what was read and ignored, and
    where it came from (`source`, for the reasons)."""
    motions: tuple[Motion, ...]
    notes: tuple[str, ...] = ()
    source: str = '<program>'


@dataclass(frozen=True)
class GcodeResult:
    """What :func:`parse` / :func:`read` came to: `status`, `reason` (``source:line:
    reason``; '' when ok) and, when ok, the `program`."""
    status: GcodeStatus
    reason: str = ''
    program: Program | None = None

    @property
    def ok(self) -> bool:
        return self.status == GcodeStatus.OK


@dataclass(frozen=True)
class Piece:
    """One tool path of a program for the planner: CL data, the feed limit (m/s; RAPID_FEED
    for a rapid), the program lines it covers and whether an M0 stops the program after it."""
    cl: toolpath.CLData
    feed: float
    rapid: bool
    lines: tuple[int, int]
    stop_after: bool = False

    @property
    def label(self) -> str:
        """'rapid' or 'feed 5 mm/s'."""
        return 'rapid' if self.rapid else f'feed {self.feed * 1e3:.4g} mm/s'

    @property
    def where(self) -> str:
        """'line 3' or 'lines 3-5'."""
        first, last = self.lines
        return f'line {first}' if first == last else f'lines {first}-{last}'


def read(path) -> GcodeResult:
    """:func:`parse` of the file at `path` (its name in the reasons)."""
    try:
        text = Path(path).read_text(encoding='utf-8-sig')
    except (OSError, UnicodeDecodeError) as exc:
        return GcodeResult(GcodeStatus.INVALID_INPUT, f'{path}: cannot read the program: {exc}')
    return parse(text, str(path))


def parse(text: str, source: str = '<program>') -> GcodeResult:
    """The program's motions, or the first refusal (``source:line: reason``)."""
    try:
        return GcodeResult(GcodeStatus.OK, '', _Reader(source).read(text))
    except GcodeError as exc:
        return GcodeResult(GcodeStatus.INVALID_INPUT, f'{source}:{exc.line}: {exc}')


@dataclass
class _Modes:
    motion: int | None = None
    plane: int = 17
    unit: float = MM
    incremental: bool = False
    inverse_time: bool = False
    feed: float | None = None                      # m/s (G94)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotary: tuple = (0.0, 0.0, 0.0)                # rad


class _Reader:
    def __init__(self, source: str):
        self.source, self.modes = source, _Modes()
        self.motions: list[Motion] = []
        self.notes: list[str] = []

    def read(self, text: str) -> Program:
        lines = text.splitlines()
        percent = 0
        for number, raw in enumerate(lines, start=1):
            if raw.strip().startswith('%'):
                percent += 1
                if percent == 2 or (percent == 1 and (self.motions or self.notes)):   # the closing %
                    self._end(number, lines)
                    break
            words = self._words(number, raw)
            if words is None:
                continue
            if self._block(number, words):             # M2 / M30
                self._end(number, lines)
                break
        return Program(tuple(self.motions), tuple(self.notes), self.source)

    def _end(self, number: int, lines: list[str]) -> None:
        rest = sum(1 for later in lines[number:] if self._words(0, later, strict=False))
        if rest:
            self.notes.append(f'line {number}: program end; the {rest} block(s) after it are not read')

    def _words(self, number: int, raw: str, strict: bool = True) -> list[tuple[str, float, str]] | None:
        """(letter, value, text) of each word of the line, None for a line without words."""
        line = _COMMENT.sub(' ', raw).split(';', 1)[0]
        if strict and ('(' in line or ')' in line):
            raise GcodeError(number, f'an unclosed or nested comment in {raw.strip()!r}')
        stripped = line.strip()
        if not stripped or stripped == '%':
            return None
        if stripped.startswith('/'):
            if strict:
                raise GcodeError(number, 'block delete (/) is not supported')
            return None
        words, at = [], 0
        for match in _WORD.finditer(line):
            if match.start() != at:
                break
            value = float(match.group(2))
            if strict and not math.isfinite(value):
                raise GcodeError(number, f'{match.group(0).strip()[:20]}...: the number is too large')
            words.append((match.group(1).upper(), value, match.group(0).strip()))
            at = match.end()
        if at != len(line) and line[at:].strip():
            if strict:
                raise GcodeError(number, f'cannot read {line[at:].strip()!r}: not a word of the subset '
                                         '(a letter and a number; no parameters, expressions or O codes)')
            return None
        return [w for w in words if w[0] != 'N'] or None

    def _block(self, number: int, words) -> bool:
        """Apply one block; True at a program end."""
        m = self.modes
        values: dict[str, float] = {}
        motion, ends, stop = None, False, False
        groups: dict[str, str] = {}
        for letter, value, text in words:
            if letter == 'G':
                group = MODAL_GROUPS.get(value)
                if group in groups:
                    raise GcodeError(number, f'{groups[group]} and {text} in one block (both set the {group})')
                if group:
                    groups[group] = text
                motion = self._g_code(number, value, text, motion)
            elif letter == 'M':
                code = int(value) if value == int(value) else None
                if code in (2, 30):
                    ends = True
                elif code == 0:
                    stop = True
                elif code in (3, 4, 5):
                    self.notes.append(f'line {number}: {text} (spindle) ignored: the simulated machines have no '
                                      'spindle')
                else:
                    raise GcodeError(number, f'{text} is not supported (M0, M2, M30 and the spindle words M3 '
                                             'M4 M5 are)')
            elif letter == 'S':
                self.notes.append(f'line {number}: {text} (spindle speed) ignored: the simulated machines have '
                                  'no spindle')
            elif letter in 'XYZIJKRF' or letter in ROTARY:
                if letter in values:
                    raise GcodeError(number, f'{letter} appears twice in the block')
                values[letter] = value
            else:
                raise GcodeError(number, f'{text}: the word {letter} is not supported')
        if motion is not None:
            m.motion = motion
        if 'F' in values:
            if values['F'] <= 0.0:
                raise GcodeError(number, f'F{values["F"]:g}: a feed rate must be positive')
            if not m.inverse_time:
                m.feed = values['F'] * m.unit / 60.0
        axes = [letter for letter in 'XYZ' + ROTARY if letter in values]
        centre = [letter for letter in 'IJKR' if letter in values]
        if axes or centre:
            self._move(number, values, axes, centre)
        elif motion is not None and motion in (2, 3):
            raise GcodeError(number, f'G{motion} without an end point or centre')
        if stop:
            if not self.motions:
                raise GcodeError(number, 'M0 before any motion')
            self.motions[-1] = replace(self.motions[-1], stop_after=True)
        return ends

    def _g_code(self, number: int, value: float, text: str, motion):
        m = self.modes
        code = int(value) if value == int(value) else None
        if code in (0, 1, 2, 3):
            if motion is not None:
                raise GcodeError(number, f'two motion codes in one block (G{motion} and {text})')
            return code
        if code in PLANES:
            m.plane = code
        elif code in (20, 21):
            unit = INCH if code == 20 else MM
            if unit != m.unit:
                m.unit, m.feed = unit, None     # a feed in the old unit is no feed in the new one
        elif code in (90, 91):
            m.incremental = code == 91
        elif code in (93, 94):
            if m.inverse_time != (code == 93):
                m.inverse_time, m.feed = code == 93, None     # LinuxCNC: a new F after either switch
        elif value not in IN_FORCE:
            raise GcodeError(number, f'{text} is not supported (see trajectory/gcode.py for the subset)')
        return motion

    def _move(self, number: int, values: dict, axes: list, centre: list) -> None:
        m = self.modes
        if m.motion is None:
            raise GcodeError(number, f'{" ".join(axes + centre)} without a motion mode (G0, G1, G2 or G3 first)')
        if centre and m.motion in (0, 1):
            raise GcodeError(number, f'{" ".join(centre)} with G{m.motion}: centre words belong to an arc (G2, G3)')
        start = m.position.copy()
        end = start.copy()
        for index, letter in enumerate('XYZ'):
            if letter in values:
                end[index] = values[letter] * m.unit + (start[index] if m.incremental else 0.0)
        rotary = list(m.rotary)
        for index, letter in enumerate(ROTARY):
            if letter in values:
                rotary[index] = math.radians(values[letter]) + (rotary[index] if m.incremental else 0.0)
        rotary = tuple(rotary)
        far = [f'{letter}{values[letter]:g}' for letter in 'IJKR' if letter in values
               and abs(values[letter]) * m.unit > MAX_COORDINATE]
        if far or np.abs(end).max() > MAX_COORDINATE:
            what = ' '.join(far) or f'the end point {np.round(end / m.unit, 6).tolist()}'
            raise GcodeError(number, f'{what}: farther than {MAX_COORDINATE:g} m from the origin, beyond the reach '
                                     'of any machine here')
        arc = self._arc(number, values, centre, start, end) if m.motion in (2, 3) else None
        motion = Motion(number, start, end, m.rotary, rotary, None, arc)
        moved = motion.length >= MIN_MOVE
        if not moved and rotary == m.rotary:
            shorter = f'a move of {motion.length:.3g} m, shorter than {MIN_MOVE:g} m' if motion.length else \
                'the block ends where it starts'
            self.notes.append(f'line {number}: no motion ({shorter})')
            return
        if not moved:
            raise GcodeError(number, 'a rotary move with the tool tip standing still: the planner takes tool-tip '
                                     'paths (this one has no length)')
        self.motions.append(replace(motion, feed=self._feed(number, values, motion.length)))
        m.position, m.rotary = end, rotary

    def _feed(self, number: int, values: dict, length: float) -> float | None:
        """The block's feed (m/s), None for a rapid."""
        m = self.modes
        if m.motion == 0:
            return None
        if m.inverse_time:
            if 'F' not in values:
                raise GcodeError(number, 'inverse time (G93): every feed block needs its own F')
            return length / (60.0 / values['F'])        # the block takes 1/F min
        if m.feed is None:
            raise GcodeError(number, 'a feed move without a feed rate (F) in the current units and feed mode')
        return m.feed

    def _arc(self, number: int, values: dict, centre: list, start, end) -> Arc:
        m = self.modes
        i, j, k = PLANES[m.plane]
        offset_letters = {17: 'IJ', 18: 'KI', 19: 'JK'}[m.plane]
        clockwise = m.motion == 2
        if 'R' in centre:
            if len(centre) > 1:
                raise GcodeError(number, 'R and I J K in one arc: give one centre')
            c = self._centre_from_radius(number, values['R'] * m.unit, start, end, (i, j), clockwise, m.unit)
        else:
            stray = [letter for letter in centre if letter not in offset_letters]
            if stray:
                raise GcodeError(number, f'{" ".join(stray)} is not in the arc plane G{m.plane} '
                                         f'(its centre words are {" ".join(offset_letters)})')
            c = start.copy()
            for axis, letter in zip((i, j), offset_letters):
                c[axis] += values.get(letter, 0.0) * m.unit
        r0 = math.hypot(start[i] - c[i], start[j] - c[j])
        r1 = math.hypot(end[i] - c[i], end[j] - c[j])
        if r0 < toolpath.MIN_SPACING:
            raise GcodeError(number, 'the arc centre is its start point (radius 0)')
        if abs(r1 - r0) > ARC_RADIUS_TOLERANCE:
            raise GcodeError(number, f'the arc end is not on its circle: {r0 / m.unit:.6g} from the centre at the '
                                     f'start, {r1 / m.unit:.6g} at the end (a difference of at most '
                                     f'{ARC_RADIUS_TOLERANCE / m.unit:.3g} is read as the same circle)')
        a0 = math.atan2(start[j] - c[j], start[i] - c[i])
        a1 = math.atan2(end[j] - c[j], end[i] - c[i])
        if clockwise:
            sweep = -((a0 - a1) % (2.0 * math.pi))
        else:
            sweep = (a1 - a0) % (2.0 * math.pi)
        if abs(sweep) * r0 < toolpath.MIN_SPACING:        # the same point: a full circle (I J K only)
            if 'R' in centre:
                raise GcodeError(number, 'an R arc that ends where it starts: a full circle needs I J K')
            sweep = -2.0 * math.pi if clockwise else 2.0 * math.pi
        return Arc(c, (i, j, k), sweep, r0, r1)

    @staticmethod
    def _centre_from_radius(number: int, radius: float, start, end, axes, clockwise: bool, unit: float) -> np.ndarray:
        i, j = axes
        chord = np.array([end[i] - start[i], end[j] - start[j]])
        d = float(np.linalg.norm(chord))
        if d < toolpath.MIN_SPACING:
            raise GcodeError(number, 'an R arc that ends where it starts: a full circle needs I J K')
        if abs(radius) < d / 2.0 - ARC_RADIUS_TOLERANCE:
            raise GcodeError(number, f'R {abs(radius) / unit:.6g} is less than half the chord '
                                     f'({d / 2.0 / unit:.6g}): no such arc')
        h = math.sqrt(max(radius * radius - d * d / 4.0, 0.0))
        left = np.array([-chord[1], chord[0]]) / d
        # counter-clockwise arcs of at most half a turn have their centre left of the chord
        side = (1.0 if not clockwise else -1.0) * (1.0 if radius > 0.0 else -1.0)
        c = np.array(start, dtype=float)
        mid = np.array([start[i] + chord[0] / 2.0, start[j] + chord[1] / 2.0]) + side * h * left
        c[i], c[j] = mid
        return c


def pieces(program: Program, tool_axis: Callable[[tuple[float, float, float]], np.ndarray] | None = None
           ) -> list[Piece]:
    """The program's tool paths (module docstring). `tool_axis(rotary)` gives the unit tool
    axis for the rotary words (A, B, C in rad); without it the tool axis is +z, and a program
    with rotary words raises GcodeError (a ValueError) naming its first such line."""
    turned = next((mo for mo in program.motions if any(mo.rotary_start) or any(mo.rotary_end)), None)
    if turned is not None and tool_axis is None:
        raise GcodeError(turned.line, 'rotary words (A B C) need a machine to turn them into a tool orientation')
    axis_of = tool_axis or (lambda _rotary: np.array([0.0, 0.0, 1.0]))
    groups: list[list[Motion]] = []
    for motion in program.motions:
        last = groups[-1][-1] if groups else None
        if (last is not None and not last.rapid and not motion.rapid and not last.stop_after
                and last.feed == motion.feed
                and float(np.dot(last.tangent(1.0), motion.tangent(0.0))) >= math.cos(JOIN_ANGLE)):
            groups[-1].append(motion)
        else:
            groups.append([motion])
    return [_piece(group, axis_of) for group in groups]


def _piece(group: list[Motion], tool_axis) -> Piece:
    points, axes = [], []
    for n, motion in enumerate(group):
        u = motion.samples()[(1 if n else 0):]
        points.append(motion.point(u))
        r0, r1 = np.array(motion.rotary_start), np.array(motion.rotary_end)
        try:
            if motion.rotary_start == motion.rotary_end:         # one orientation for the whole block
                axes.extend([tool_axis(motion.rotary_start)] * len(u))
            else:
                axes.extend(tool_axis(tuple(r0 + t * (r1 - r0))) for t in u)
        except ValueError as exc:
            raise GcodeError(motion.line, str(exc)) from None
    first, last = group[0], group[-1]
    try:
        cl = toolpath.CLData(np.vstack(points), np.array(axes))
    except toolpath.CLDataError as exc:
        raise GcodeError(first.line, f'the tool path of this piece: {exc}') from None
    feed = RAPID_FEED if first.rapid else first.feed
    return Piece(cl, feed, first.rapid, (first.line, last.line), last.stop_after)


def tool_axis_of(kinematics, machine) -> Callable[[tuple[float, float, float]], np.ndarray]:
    """The tool axis (workpiece frame) for rotary words A, B, C (rad) on `machine`: each word
    sets the rotary axis named by its letter (``a``), or else the one rotary axis whose name
    starts with it (``a_f``); the other axes at home. Raises ValueError naming a word with no
    such axis when it is used (a nonzero angle)."""
    names = machine.axis_names
    rotary = [a.name for a in machine.axes if a.kind == 'rotary']
    index = {}
    for letter in ROTARY:
        low = letter.lower()
        match = [n for n in rotary if n == low] or [n for n in rotary if n.startswith(low + '_')]
        if len(match) == 1:
            index[letter] = names.index(match[0])

    def tool_axis(angles: tuple[float, float, float]) -> np.ndarray:
        q = np.array(machine.home, dtype=float)
        for letter, angle in zip(ROTARY, angles):
            if angle == 0.0:
                continue
            if letter not in index:
                raise ValueError(f'{machine.name} has no rotary axis for {letter} (its rotary axes: '
                                 f'{" ".join(rotary) or "none"})')
            q[index[letter]] = angle
        return kinematics.forward(q)[1]
    return tool_axis
