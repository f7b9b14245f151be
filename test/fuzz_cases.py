"""Hostile inputs for the graph fuzzing campaign (test/test_fuzz_graph.py): hypothesis
strategies for every message type the nodes subscribe to, for parameter sets and for
service calls, and the oracle that says what the running graph must do with each.

A case is valid-shaped (it serializes as its ROS type) with content a rogue publisher or a
broken client could send: random lengths and names (real axes, unknown, duplicated, empty,
non-ASCII), NaN, inf, +-1e308, subnormal values, empty fields, wrong frames, stamps off the
control grid, with nanosec >= 1e9, far ahead, long past or negative.

Every topic case is *invalid*. Where the README ("Bringup and the command API") says a
well-formed message is trusted, whoever sends it — a /reference or /trajectory/reference
chunk replaces the buffered reference, a non-finite /servo_commands value faults the
machine, an on-grid /clock ahead of the sim time moves the trajectory node's time, an
ERROR status named hw_sim on /diagnostics faults the trajectory node — the strategies add
a defect the README says is refused (or leave the by-design case out, said where), so
nothing sent may move the machine. :func:`effects` is the oracle: per node counter, how
many refusals the case adds (README: a refused input is counted on /diagnostics or
/trajectory/status with its reason; a stale one is ignored).

Cases are plain frozen data (their repr is the falsifying example hypothesis prints);
:meth:`message` builds the ROS message. No ROS import at module level, so collection costs
nothing when the graph tests are not run.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace

from hypothesis import strategies as st

from machine_ctrl import contract
from machine_ctrl.model.config import load_machine
from trajectory.axis_limits import unlimited_range

MACHINE = load_machine('micromill_9axis')
PERIOD_NS = contract.StepClock.of(MACHINE).period_ns
STEPS_PER_SECOND = contract.NS_PER_SECOND // PERIOD_NS
AXES = tuple(MACHINE.axis_names)
_FINE_TYPES = {MACHINE.axis(p.fine).drive.type for p in MACHINE.dual_stage}
COARSE = tuple(a.name for a in MACHINE.axes if a.control is not None and a.drive.type not in _FINE_TYPES)
FINE = tuple(a.name for a in MACHINE.axes if a.control is not None and a.drive.type in _FINE_TYPES)
OFFSET_AXES = MACHINE.offset_axes            # what servo_fine reads on dual_stage/offsets
WORKPIECE = MACHINE.workpiece_frame
INT32 = (-2**31, 2**31 - 1)
UINT32_MAX = 2**32 - 1

# Topic names, relative as in the contract (the graph runs in the root namespace).
JOINT_STATES = contract.JOINT_STATES.name
OFFSETS = contract.DUAL_STAGE_OFFSETS.name
SERVO_COMMANDS = contract.SERVO_COMMANDS.name
REFERENCE = contract.REFERENCE.name
TRAJECTORY_REFERENCE = contract.TRAJECTORY_REFERENCE.name
CLOCK = contract.CLOCK.name
DIAGNOSTICS = contract.DIAGNOSTICS.name
PATH = contract.PATH.name
JOINT_GOAL = contract.JOINT_GOAL.name
FEED_OVERRIDE = contract.FEED_OVERRIDE.name
PROGRAM = contract.PROGRAM.name
GOAL_TOPICS = {PATH: 'path', JOINT_GOAL: 'joint goal', FEED_OVERRIDE: 'feed override',      # -> Rejections `what`
               PROGRAM: 'program'}

# Who reads what (machine_ctrl/ros/*_node.py), and the axes each needs from the message.
REFERENCE_READERS = {'servo_coarse': COARSE, 'servo_fine': FINE, 'dual_stage': AXES, 'contour_error': AXES}
STEP_NODES = ('servo_coarse', 'servo_fine', 'dual_stage')       # StepAnswerer: stale states ignored
REJECTED = 'rejected_messages'
# Prefixes of `last_rejection` (Rejections: '<what>: <reason>') by node counter.
REASON_PREFIXES = {
    ('servo_coarse', REJECTED): ('state: ', 'reference: ', 'clock: '),
    ('servo_fine', REJECTED): ('state: ', 'reference: ', 'offsets: ', 'clock: '),
    ('dual_stage', REJECTED): ('state: ', 'reference: ', 'clock: '),
    ('contour_error', REJECTED): ('state: ', 'reference: ', 'clock: '),
    ('compensation', 'rejected_chunks'): ('reference chunk: ',),
    ('hw_sim', 'refused_commands'): ('',),
}
REASON_KEYS = {'hw_sim': 'last_refusal'}                          # else 'last_rejection'
COUNTERS = (REJECTED, 'rejected_chunks', 'refused_commands', 'stale_commands', 'step', 'answered_step', 'last_step')


# --- values ---------------------------------------------------------------------------------
NASTY = (math.nan, math.inf, -math.inf, 1e308, -1e308, sys.float_info.max, -sys.float_info.max, 1e-308, -1e-308,
         5e-324, -5e-324, 0.0, -0.0)
nasty = st.sampled_from(NASTY)
any_float = st.one_of(nasty, st.floats(), st.floats(-1e-3, 1e-3))
# inside every stroke of the micromill (the fine strokes are +-100 um, +-8.7 mrad)
small = st.one_of(st.sampled_from((0.0, -0.0, 1e-308, 5e-324, -5e-324)), st.floats(-5e-5, 5e-5))
non_finite = st.sampled_from((math.nan, math.inf, -math.inf))
# No NUL: rclpy cuts a string at its first NUL when it publishes ('x_c\0q' goes out as 'x_c',
# a real axis), so a NUL would turn an invalid name into a valid one behind the oracle's back.
text = st.text(st.characters(exclude_categories=('Cs',), exclude_characters='\x00'), max_size=10)
STRANGE_NAMES = ('', 'q', 'x_c ', ' x_c', 'X_C', 'x_c/x_f', 'é', '\U0001f6e0', 'hw_sim', 'a' * 300)
unknown_name = st.one_of(st.sampled_from(STRANGE_NAMES), text).filter(lambda s: s not in AXES)
name = st.one_of(st.sampled_from(AXES), unknown_name)
frame = st.one_of(st.sampled_from(('', WORKPIECE, 'map', 'base', 'Workpiece', WORKPIECE + ' ', '/' + WORKPIECE)), text)


# --- stamps ---------------------------------------------------------------------------------
def on_grid(step: int) -> tuple[int, int]:
    return contract.split_ns(step * PERIOD_NS)


off_grid = st.builds(lambda sec, k, r: (sec, k * PERIOD_NS + r), st.integers(*INT32),
                     st.integers(0, STEPS_PER_SECOND - 1), st.integers(1, PERIOD_NS - 1))
overflow = st.tuples(st.integers(*INT32), st.integers(contract.NS_PER_SECOND, UINT32_MAX))     # nanosec >= 1e9
# >= 1e5 s of sim time ahead: never reached by a test; up to the last int32 second
future = st.integers(10**9, INT32[1] * STEPS_PER_SECOND).map(on_grid)
# long past (the graph is beyond step 3000 when the campaign starts) or negative
past = st.integers(INT32[0] * STEPS_PER_SECOND, 1000).map(on_grid)
STAMPS = {'off_grid': off_grid, 'overflow': overflow, 'future': future, 'past': past}
any_stamp = st.one_of(*STAMPS.values())


def stamp_step(stamp) -> int | None:
    """The control step of a stamp, or None when it is not one (nanosec out of range, off grid)."""
    sec, nanosec = stamp
    if not 0 <= nanosec < contract.NS_PER_SECOND:
        return None
    step, rest = divmod(sec * contract.NS_PER_SECOND + nanosec, PERIOD_NS)
    return None if rest else step


# --- the cases ------------------------------------------------------------------------------
@dataclass(frozen=True)
class StateCase:
    """sensor_msgs/JointState on joint_states, dual_stage/offsets or servo_commands."""
    topic: str
    kind: str                        # stamp class (+ the content defect added)
    stamp: tuple[int, int]
    frame: str
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]

    def message(self):
        from sensor_msgs.msg import JointState
        msg = JointState(name=list(self.name), position=list(self.position), velocity=list(self.velocity),
                         effort=list(self.effort))
        msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp
        msg.header.frame_id = self.frame
        return msg


@dataclass(frozen=True)
class ChunkCase:
    """trajectory_msgs/JointTrajectory on reference or trajectory/reference, compact: point i
    holds rows[i % len(rows)] and the common velocities and accelerations, but for the
    `overrides` (point, field, values) and the `offsets` (point, sec, nanosec)."""
    topic: str
    kind: str                        # the defects added
    stamp: tuple[int, int]
    frame: str
    names: tuple[str, ...]
    n_points: int
    rows: tuple[tuple[float, ...], ...]
    velocities: tuple[float, ...]
    accelerations: tuple[float, ...]
    overrides: tuple[tuple[int, str, tuple[float, ...]], ...] = ()
    offsets: tuple[tuple[int, int, int], ...] = ()

    def points(self):
        """(positions, velocities, accelerations, (sec, nanosec)) of every point."""
        changed = {(i, field): values for i, field, values in self.overrides}
        moved = {i: (sec, nanosec) for i, sec, nanosec in self.offsets}
        for i in range(self.n_points):
            yield (changed.get((i, 'positions'), self.rows[i % len(self.rows)]),
                   changed.get((i, 'velocities'), self.velocities),
                   changed.get((i, 'accelerations'), self.accelerations),
                   moved.get(i, contract.split_ns(i * PERIOD_NS)))

    def message(self):
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
        msg = JointTrajectory(joint_names=list(self.names))
        msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp
        msg.header.frame_id = self.frame
        msg.points = [JointTrajectoryPoint(positions=list(p), velocities=list(v), accelerations=list(a),
                                           time_from_start=Duration(sec=t[0], nanosec=t[1]))
                      for p, v, a, t in self.points()]
        return msg


@dataclass(frozen=True)
class ProgramCase:
    """std_msgs/String: a G-code program's text."""
    topic: str
    kind: str
    text: str

    def message(self):
        from std_msgs.msg import String
        return String(data=self.text)


@dataclass(frozen=True)
class ClockCase:
    topic: str
    kind: str
    stamp: tuple[int, int]

    def message(self):
        from rosgraph_msgs.msg import Clock
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = self.stamp
        return msg


@dataclass(frozen=True)
class DiagnosticsCase:
    """diagnostic_msgs/DiagnosticArray: statuses (level, name, message, hardware_id, values)."""
    topic: str
    kind: str
    stamp: tuple[int, int]
    statuses: tuple[tuple[int, str, str, str, tuple[tuple[str, str], ...]], ...]

    def message(self):
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        msg = DiagnosticArray(status=[
            DiagnosticStatus(level=bytes([level]), name=name, message=message, hardware_id=hardware_id,
                             values=[KeyValue(key=k, value=v) for k, v in values])
            for level, name, message, hardware_id, values in self.statuses])
        msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp
        return msg


@dataclass(frozen=True)
class PathCase:
    """nav_msgs/Path: poses (frame, (x, y, z), (qx, qy, qz, qw))."""
    topic: str
    kind: str
    stamp: tuple[int, int]
    frame: str
    poses: tuple[tuple[str, tuple[float, float, float], tuple[float, float, float, float]], ...]

    def message(self):
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path
        msg = Path()
        msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp
        msg.header.frame_id = self.frame
        for pose_frame, p, q in self.poses:
            pose = PoseStamped()
            pose.header.frame_id = pose_frame
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = p
            o = pose.pose.orientation
            o.x, o.y, o.z, o.w = q
            msg.poses.append(pose)
        return msg


@dataclass(frozen=True)
class GoalCase:
    """trajectory_msgs/JointTrajectory on trajectory/joint_goal; times (sec, nanosec) per
    point, or None: all zero (time-optimal)."""
    topic: str
    kind: str
    stamp: tuple[int, int]
    frame: str
    names: tuple[str, ...]
    points: tuple[tuple[float, ...], ...]
    times: tuple[tuple[int, int], ...] | None

    def message(self):
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
        msg = JointTrajectory(joint_names=list(self.names))
        msg.header.stamp.sec, msg.header.stamp.nanosec = self.stamp
        msg.header.frame_id = self.frame
        for i, values in enumerate(self.points):
            point = JointTrajectoryPoint(positions=list(values))
            if self.times is not None:
                point.time_from_start.sec, point.time_from_start.nanosec = self.times[i]
            msg.points.append(point)
        return msg


@dataclass(frozen=True)
class OverrideCase:
    topic: str
    kind: str
    value: float

    def message(self):
        from std_msgs.msg import Float64
        return Float64(data=self.value)


# --- the oracle -------------------------------------------------------------------------------
def state_problem(names, values, wanted) -> str | None:
    """Why a JointState field is refused by a node that needs `wanted` from it
    (messages.select), or None."""
    if len(values) != len(names):
        return 'length'
    if len(set(names)) != len(names):
        return 'duplicate'
    if any(w not in names for w in wanted):
        return 'missing'
    if not all(math.isfinite(values[names.index(w)]) for w in wanted):
        return 'non-finite'
    return None


def chunk_problem(case: ChunkCase, wanted) -> str | None:
    """Why a reference chunk is refused by a node that needs `wanted` (messages.parse_chunk),
    or None."""
    names = case.names
    if len(set(names)) != len(names):
        return 'duplicate'
    if any(w not in names for w in wanted):
        return 'missing'
    if case.n_points == 0:
        return 'no points'
    if stamp_step(case.stamp) is None:
        return 'stamp'
    picks = [names.index(w) for w in wanted]
    for i, (p, v, a, t) in enumerate(case.points()):
        if t[0] * contract.NS_PER_SECOND + t[1] != i * PERIOD_NS:
            return 'offset'
        for values in (p, v or (0.0,) * len(names), a or (0.0,) * len(names)):
            if len(values) != len(names):
                return 'length'
            if not all(math.isfinite(values[c]) for c in picks):
                return 'non-finite'
    return None


def effects(case) -> dict[tuple[str, str], tuple[int, int | None]]:
    """(node, counter) -> (least, most) refusals the case adds (most None: no bound)."""
    stamp_class = case.kind.split('+')[0]
    if case.topic in GOAL_TOPICS:
        return {('trajectory', 'rejected_goals'): (1, 1)}
    if case.topic == JOINT_STATES:
        # the step nodes ignore a state of a step already taken (stale), refuse any other
        # here (off grid, or skipping ahead); contour_error checks the content first
        out = {(node, REJECTED): (0, 0) if stamp_class == 'past' else (1, 1) for node in STEP_NODES}
        out[('contour_error', REJECTED)] = (1, 1)
        return out
    if case.topic == OFFSETS:
        return {('servo_fine', REJECTED): (1, 1)}
    if case.topic == SERVO_COMMANDS:
        if stamp_class == 'past':
            return {('hw_sim', 'stale_commands'): (1, None)}
        if stamp_class == 'future':
            return {('hw_sim', 'refused_commands'): (1, 1)}
        # off grid / nanosec out of range: refused and counted
        # (test_an_off_grid_servo_command_is_counted_on_diagnostics)
        return {('hw_sim', 'refused_commands'): (1, 1)}
    if case.topic == REFERENCE:
        return {(node, REJECTED): (1, 1) if chunk_problem(case, wanted) else (0, 0)
                for node, wanted in REFERENCE_READERS.items()}
    if case.topic == TRAJECTORY_REFERENCE:
        return {('compensation', 'rejected_chunks'): (1, 1) if chunk_problem(case, AXES) else (0, 0)}
    if case.topic == CLOCK:
        # no time (node_common.use_sim_time): refused by the nodes on the clock that count, if
        # its reader takes it: rclpy's clock reader keeps the last message only (hw_sim's clock
        # and the batch's next one may replace it first)
        no_time = case.stamp[0] < 0 or not 0 <= case.stamp[1] < contract.NS_PER_SECOND
        return {(node, REJECTED): (0, 1) if no_time else (0, 0) for node in (*STEP_NODES, 'contour_error')}
    return {}         # /diagnostics: ignored (not counted), README


# --- strategies: per-step states ----------------------------------------------------------------
@st.composite
def state_content(draw, wanted):
    """(names, values) of one JointState field: near valid for `wanted` (every axis once,
    maybe unknown extras, finite values) or anything."""
    if draw(st.booleans()):
        extras = draw(st.lists(unknown_name, max_size=3, unique=True))
        names = draw(st.permutations(list(wanted) + extras))
        values = draw(st.lists(small, min_size=len(names), max_size=len(names)))
    else:
        names = draw(st.lists(name, max_size=12))
        n = draw(st.one_of(st.just(len(names)), st.integers(0, 14)))
        values = draw(st.lists(any_float, min_size=n, max_size=n))
    return list(names), list(values)


@st.composite
def break_state(draw, names, values, wanted):
    """A content the `wanted` reader refuses (the content given is valid for it)."""
    defect = draw(st.sampled_from(('missing', 'duplicate', 'length', 'non-finite')))
    names, values = list(names), list(values)
    if defect == 'missing':
        gone = draw(st.sampled_from(wanted))
        keep = [i for i, n in enumerate(names) if n != gone]
        names, values = [names[i] for i in keep], [values[i] for i in keep]
    elif defect == 'duplicate':
        names.append(names[draw(st.integers(0, len(names) - 1))])
        values.append(draw(small))
    elif defect == 'length':
        if values and draw(st.booleans()):
            values.pop(draw(st.integers(0, len(values) - 1)))
        else:
            values.insert(draw(st.integers(0, len(values))), draw(any_float))
    else:
        values[names.index(draw(st.sampled_from(wanted)))] = draw(non_finite)
    assert state_problem(names, values, wanted) is not None
    return defect, names, values


def _others(names):
    return st.one_of(st.lists(any_float, max_size=12), st.lists(small, min_size=len(names), max_size=len(names)))


@st.composite
def joint_states(draw):
    """A state on joint_states: off grid or nanosec out of range (refused by every reader),
    or on grid far ahead (the step nodes refuse a skip ahead) or long past (ignored as
    stale), then always with a content contour_error refuses: it has no skip-ahead check
    and would take a well-formed future state (test_a_well_formed_future_state_...)."""
    kind = draw(st.sampled_from(tuple(STAMPS)))
    names, position = draw(state_content(AXES))
    if kind in ('future', 'past') and state_problem(names, position, AXES) is None:
        defect, names, position = draw(break_state(names, position, AXES))
        kind += '+' + defect
    return StateCase(JOINT_STATES, kind, draw(STAMPS[kind.split('+')[0]]), draw(frame), tuple(names),
                     tuple(position), tuple(draw(_others(names))), tuple(draw(_others(names))))


@st.composite
def offsets(draw):
    """dual_stage/offsets for servo_fine: off grid / out of range, or on grid with a content
    it refuses (well-formed offsets of a step are taken, whoever sends them)."""
    kind = draw(st.sampled_from(tuple(STAMPS)))
    names, position = draw(state_content(OFFSET_AXES))
    if kind in ('future', 'past') and state_problem(names, position, OFFSET_AXES) is None:
        defect, names, position = draw(break_state(names, position, OFFSET_AXES))
        kind += '+' + defect
    return StateCase(OFFSETS, kind, draw(STAMPS[kind.split('+')[0]]), draw(frame), tuple(names), tuple(position),
                     tuple(draw(_others(names))), tuple(draw(_others(names))))


@st.composite
def servo_commands(draw):
    """servo_commands for hw_sim, for a step it is not at: far ahead (refused), long past
    (stale), off grid / out of range (refused). Left out: on grid, as many values as names
    and a non-finite one faults the machine by design (README; test_robustness). Finite
    values whose sum overflows (1e308 + 1e308) stay in: they are refused like any other
    (test_finite_commands_beyond_the_float_range_...)."""
    kind = draw(st.sampled_from(tuple(STAMPS)))
    names, effort = draw(state_content(AXES))
    if kind in ('future', 'past') and len(effort) == len(names) and not all(math.isfinite(v) for v in effort):
        effort = [v if math.isfinite(v) else 0.0 for v in effort]
    return StateCase(SERVO_COMMANDS, kind, draw(STAMPS[kind]), draw(frame), tuple(names),
                     tuple(draw(_others(names))), tuple(draw(_others(names))), tuple(effort))


# --- strategies: reference chunks ---------------------------------------------------------------
CHUNK_DEFECTS = ('duplicate', 'missing', 'no points', 'off_grid', 'overflow', 'offset', 'length', 'non-finite')


def _row(width):
    return st.lists(small, min_size=width, max_size=width).map(tuple)


@st.composite
def chunks(draw, topic):
    """A chunk every reader of `topic` refuses: a near-valid one (all axes, maybe extras,
    1..600 points on the grid, far ahead or long past) or a random one, with one or more
    defects added until no reader would take it (a well-formed chunk replaces the buffered
    reference from its first step, README)."""
    if draw(st.booleans()):
        extras = draw(st.lists(unknown_name, max_size=2, unique=True))
        names = tuple(draw(st.permutations(list(AXES) + extras)))
        width = len(names)
        rows = tuple(draw(st.lists(_row(width), min_size=1, max_size=3)))
        n = draw(st.one_of(st.integers(1, 5), st.integers(1, 600)))
        velocities = draw(st.one_of(st.just(()), _row(width)))
        accelerations = draw(st.one_of(st.just(()), _row(width)))
    else:
        names = tuple(draw(st.lists(name, max_size=12)))
        rows = tuple(draw(st.lists(st.lists(any_float, max_size=14).map(tuple), min_size=1, max_size=3)))
        n = draw(st.integers(0, 20))
        velocities = tuple(draw(st.lists(any_float, max_size=12)))
        accelerations = tuple(draw(st.lists(any_float, max_size=12)))
    case = ChunkCase(topic, '', draw(st.one_of(future, past)), draw(frame), names, n, rows, velocities, accelerations)
    wanted = REFERENCE_READERS.values() if topic == REFERENCE else (AXES,)
    defects = []
    while not defects or any(chunk_problem(case, w) is None for w in wanted):
        defect = draw(st.sampled_from(CHUNK_DEFECTS))
        case = draw(_break_chunk(case, defect))
        defects.append(defect)
    return replace(case, kind='+'.join(defects))


@st.composite
def _break_chunk(draw, case: ChunkCase, defect: str):
    names, rows = list(case.names), [list(r) for r in case.rows]
    n = case.n_points
    if defect in ('offset', 'length', 'non-finite') and n == 0:
        defect = 'off_grid'
    if defect == 'duplicate':
        names.append(names[draw(st.integers(0, len(names) - 1))] if names else 'x_c')
        if not case.names:
            names.append('x_c')
        extra = len(names) - len(case.names)
        return replace(case, names=tuple(names), rows=tuple(tuple(r + [0.0] * extra) for r in rows),
                       velocities=case.velocities + (0.0,) * extra if case.velocities else (),
                       accelerations=case.accelerations + (0.0,) * extra if case.accelerations else ())
    if defect == 'missing':      # a coarse and a fine axis: every reader misses one
        gone = {draw(st.sampled_from(COARSE)), draw(st.sampled_from(FINE))}
        keep = [i for i, n_ in enumerate(names) if n_ not in gone]

        def cut(values):
            return tuple(values[i] for i in keep if i < len(values)) if len(values) == len(names) else tuple(values)
        return replace(case, names=tuple(names[i] for i in keep), rows=tuple(cut(r) for r in rows),
                       velocities=cut(case.velocities), accelerations=cut(case.accelerations), overrides=())
    if defect == 'no points':
        return replace(case, n_points=0, overrides=(), offsets=())
    if defect in ('off_grid', 'overflow'):
        return replace(case, stamp=draw(STAMPS[defect]))
    i = draw(st.integers(0, n - 1))
    if defect == 'offset':
        good = i * PERIOD_NS
        ns = draw(st.one_of(st.integers(0, 10**12), st.just(good + 1), st.just(max(good - PERIOD_NS, 1)))
                  .filter(lambda v: v != good))
        sec, nanosec = draw(st.one_of(st.just(contract.split_ns(ns)),
                                      st.tuples(st.integers(*INT32), st.integers(contract.NS_PER_SECOND, UINT32_MAX))))
        return replace(case, offsets=case.offsets + ((i, sec, nanosec),))
    field = draw(st.sampled_from(('positions', 'velocities', 'accelerations')))
    width = len(names)
    if defect == 'length':
        size = draw(st.integers(0, width + 3).filter(lambda k: k != width and (k > 0 or field == 'positions')))
        values = tuple(draw(st.lists(small, min_size=size, max_size=size)))
    else:   # non-finite: in a coarse and a fine column of point i (every reader picks one)
        base = {'positions': rows[i % len(rows)], 'velocities': case.velocities,
                'accelerations': case.accelerations}[field]
        values = list(base) if len(base) == width else [0.0] * width
        for axis in (draw(st.sampled_from(COARSE)), draw(st.sampled_from(FINE))):
            for c, n_ in enumerate(names):
                if n_ == axis:
                    values[c] = draw(non_finite)
        values = tuple(values)
    return replace(case, overrides=case.overrides + ((i, field, values),))


# --- strategies: clock, diagnostics -----------------------------------------------------------
@st.composite
def clocks(draw):
    """/clock that no node may take as the sim time: off grid, nanosec out of range,
    negative, or long past (an on-grid clock ahead of the sim time is trusted, README)."""
    kind = draw(st.sampled_from(('off_grid', 'overflow', 'negative', 'past')))
    if kind == 'negative':
        stamp = draw(st.tuples(st.integers(INT32[0], -1), st.integers(0, UINT32_MAX)))
    elif kind == 'past':
        stamp = on_grid(draw(st.integers(0, 1000)))
    else:
        stamp = draw(STAMPS[kind])
    return ClockCase(CLOCK, kind, stamp)


DIAG_NAMES = ('hw_sim', 'hw_sim ', 'HW_SIM', 'hw_sim/goal', 'trajectory', 'trajectory/goal', 'servo_coarse', '')
DIAG_VALUES = ('', 'not a step', '-1', '1e308', 'nan', '9' * 40, '²', '0x10')
ERROR = 2


@st.composite
def diagnostics(draw):
    """/diagnostics statuses of any name, level (0..255), message and values. Left out by
    design: an ERROR status named hw_sim faults the trajectory node (the node learns
    hw_sim's faults there; test_a_rogue_hw_sim_fault_status_is_trusted_as_documented)."""
    statuses = []
    for _ in range(draw(st.integers(0, 5))):
        status_name = draw(st.one_of(st.sampled_from(DIAG_NAMES), text))
        level = draw(st.one_of(st.integers(0, 3), st.integers(0, 255)))
        if status_name == 'hw_sim' and level == ERROR:
            level = 0
        values = tuple(draw(st.lists(st.tuples(st.one_of(st.sampled_from(('step', 'fault', 'level')), text),
                                               st.one_of(st.sampled_from(DIAG_VALUES), text)), max_size=6)))
        statuses.append((level, status_name, draw(text), draw(text), values))
    return DiagnosticsCase(DIAGNOSTICS, f'{len(statuses)} statuses', draw(any_stamp), tuple(statuses))


# --- strategies: commands -------------------------------------------------------------------
def _home_tip():
    import numpy as np

    from machine_ctrl.model.kinematics import Kinematics
    tip, _ = Kinematics.from_config(MACHINE).forward(np.zeros(len(AXES)))
    return tuple(float(v) for v in tip)


HOME_TIP = _home_tip()
UNIT_Q = (0.0, 0.0, 0.0, 1.0)
PATH_DEFECTS = ('frame', 'pose frame', 'few', 'non-finite', 'quaternion', 'repeat', 'unreachable')


@st.composite
def paths(draw):
    """A tool path near the home tool tip (6..30 distinct poses, unit quaternions: a path
    the machine could run) with one or two of the refusals of the README's table: header
    frame, pose frame, fewer than 6 poses, NaN/inf, quaternion zero / not unit / not finite,
    a repeated point, a tool tip beyond the workspace (>= 1 m away: planning fails)."""
    n = draw(st.integers(6, 30))
    x = HOME_TIP[0]
    poses = []
    for _ in range(n):
        x += draw(st.floats(2e-5, 5e-4))
        p = (x, HOME_TIP[1] + draw(st.floats(-1e-4, 1e-4)), HOME_TIP[2] + draw(st.floats(-1e-4, 1e-4)))
        tilt = draw(st.floats(-0.01, 0.01))
        q = draw(st.sampled_from((UNIT_Q, (math.sin(tilt / 2), 0.0, 0.0, math.cos(tilt / 2)))))
        poses.append([draw(st.sampled_from(('', WORKPIECE))), p, q])
    header = WORKPIECE
    defects = draw(st.lists(st.sampled_from(PATH_DEFECTS), min_size=1, max_size=2, unique=True))
    if 'few' in defects:                  # first: the others then act on what is left
        poses = poses[:draw(st.integers(0, 5))]
    for defect in defects:
        if defect == 'few' or (not poses and defect != 'frame'):
            continue
        i = draw(st.integers(0, max(len(poses) - 1, 0)))
        if defect == 'frame':
            header = draw(frame.filter(lambda f: f != WORKPIECE))
        elif defect == 'pose frame':
            poses[i][0] = draw(frame.filter(lambda f: f not in ('', WORKPIECE)))
        elif defect == 'non-finite':
            p = list(poses[i][1])
            p[draw(st.integers(0, 2))] = draw(non_finite)
            poses[i][1] = tuple(p)
        elif defect == 'quaternion':
            scale = draw(st.one_of(st.just(0.0), st.floats(0.0, 0.99), st.floats(1.01, 1e300), st.just(1e308)))
            q = [v * scale for v in poses[i][2]]
            if draw(st.booleans()):
                q[draw(st.integers(0, 3))] = draw(non_finite)
            poses[i][2] = tuple(q)
        elif defect == 'repeat':
            if len(poses) > 1:
                j = min(i, len(poses) - 2)
                poses[j + 1][1] = poses[j][1]
            else:
                defects.append('few')
        else:   # unreachable
            p = list(poses[i][1])
            away = draw(st.one_of(st.floats(1.0, 1e3), st.just(1e308)))
            p[draw(st.integers(0, 2))] += draw(st.sampled_from((away, -away)))
            poses[i][1] = tuple(p)
    return PathCase(PATH, '+'.join(defects), draw(any_stamp), header, tuple((f, tuple(p), tuple(q)) for f, p, q in poses))


GOAL_DEFECTS = ('no names', 'duplicate', 'unknown', 'no points', 'length', 'non-finite', 'stroke', 'times')


def _beyond(axis: str):
    """A position of `axis` it does not accept: outside its stroke, or beyond the range
    float rounding allows on an unlimited axis (axis_limits.unlimited_range: 2^31 rad on c_f)."""
    a = MACHINE.axis(axis)
    bound = unlimited_range(a, MACHINE.control_period)
    low, high = a.stroke if a.stroke else (-bound, bound)
    return st.one_of(st.floats(1e-3, 1e3).map(lambda d: high + d), st.floats(1e-3, 1e3).map(lambda d: low - d),
                     st.sampled_from((1e308, -1e308)))


@st.composite
def joint_goals(draw):
    """Axis goals (a subset of the axes, 1..4 points inside the strokes, times all zero or
    increasing) with one or two of the README's refusals: no names, a duplicate or unknown
    name, no points, a length mismatch, NaN/inf, outside the stroke / beyond the range of c_f,
    a negative, non-increasing or too long (> 2^20 control steps) time_from_start."""
    names = draw(st.lists(st.sampled_from(AXES), min_size=1, max_size=len(AXES), unique=True))
    k = draw(st.integers(1, 4))
    points = [[draw(small) for _ in names] for _ in range(k)]
    times = None
    if draw(st.booleans()):
        t, times = 0, []
        for _ in range(k):
            t += draw(st.integers(5 * 10**7, 2 * 10**9))     # ns
            times.append(contract.split_ns(t))
    defects = draw(st.lists(st.sampled_from(GOAL_DEFECTS), min_size=1, max_size=2, unique=True))
    for defect in sorted(defects, key=lambda d: d in ('no names', 'no points')):    # those last
        if defect == 'duplicate':
            names.append(names[draw(st.integers(0, len(names) - 1))])
            for p in points:
                p.append(draw(small))
        elif defect == 'unknown':
            names[draw(st.integers(0, len(names) - 1))] = draw(unknown_name)
        elif defect == 'length':
            p = points[draw(st.integers(0, len(points) - 1))]
            if p and draw(st.booleans()):
                p.pop()
            else:
                p.append(draw(small))
        elif defect == 'non-finite':
            p = points[draw(st.integers(0, len(points) - 1))]
            if p:
                p[draw(st.integers(0, len(p) - 1))] = draw(non_finite)
            else:
                p.append(draw(non_finite))
        elif defect == 'stroke':
            c = draw(st.integers(0, len(names) - 1))
            axis, p = names[c], points[draw(st.integers(0, len(points) - 1))]
            if axis not in AXES:
                defects.append('unknown')
            elif c >= len(p):               # a point cut short by 'length'
                defects.append('length')
            else:
                p[c] = draw(_beyond(axis))
        elif defect == 'times':
            how = draw(st.sampled_from(('negative', 'not increasing', 'too long')))
            times = list(times) if times is not None else [(0, 0)] * len(points)
            j = draw(st.integers(0, len(points) - 1))
            if how == 'negative':
                times[j] = (draw(st.integers(INT32[0], -1)), draw(st.integers(0, 999_999_999)))
            elif how == 'not increasing' and len(points) > 1:
                j = min(j, len(points) - 2)
                later = times[j] if times[j] != (0, 0) else (0, 100_000_000)
                times[j] = later
                times[j + 1] = draw(st.sampled_from((later, (0, 0), (later[0], max(later[1] - 1, 0)))))
            else:       # too long: the last point beyond 2^20 control steps (104.9 s)
                times[-1] = (draw(st.integers(105, INT32[1])), draw(st.integers(0, 999_999_999)))
            times = tuple(times)
        elif defect == 'no names':
            names = []
        elif defect == 'no points':
            points, times = [], (() if times is not None else None)
    return GoalCase(JOINT_GOAL, '+'.join(defects), draw(any_stamp), draw(frame), tuple(names),
                    tuple(tuple(p) for p in points), times)


@st.composite
def overrides(draw):
    """A feed override that is not a finite fraction within [0, 1] (-0.0 is one: left out)."""
    value = draw(st.one_of(non_finite, st.floats(min_value=1.0, exclude_min=True),
                           st.floats(max_value=-5e-324), st.sampled_from((1e308, -1e308, 1.0000000000000002))))
    return OverrideCase(FEED_OVERRIDE, 'not finite' if not math.isfinite(value) else 'outside [0, 1]', value)


# blocks the G-code reader refuses (test_gcode: each with its reason), whatever follows
PROGRAM_DEFECTS = ('G43 H1', 'M8', 'T1 M6', 'G0 X#1', 'G0 X[1+2]', '/G0 X1', 'G0 X1 X2', 'X1', 'G0 X1 G1',
                   'G1 X1 F0', 'G0 X1 (open', 'M' + '9' * 400, 'G1 X100000 F100', 'G20 G21 G0 X1', '\x01', 'O100')


@st.composite
def programs(draw):
    """A program whose first block is one the reader refuses, then anything: random text
    (any characters, long lines) or blocks that would move (a program is read whole before
    anything is planned, so none of it may move the machine)."""
    defect = draw(st.sampled_from(PROGRAM_DEFECTS))
    # no NUL: a ROS string cannot carry one (rclpy refuses to publish it)
    blocks = st.one_of(st.text(st.characters(blacklist_characters='\x00'), max_size=200), st.sampled_from(('G0 X0.001', 'G1 X0.002 F600', 'G2 X0 Y0 I0.001 F60',
                                                                 'M30', '%', '(comment)', '')))
    rest = draw(st.lists(blocks, max_size=20))
    return ProgramCase(PROGRAM, defect, '\n'.join([defect, *rest]))


TOPIC_STRATEGIES = (joint_goals(), paths(), chunks(REFERENCE), chunks(TRAJECTORY_REFERENCE), joint_states(),
                    offsets(), servo_commands(), overrides(), clocks(), diagnostics(), programs())


def batches(size: int):
    """At least `size` cases, as many of each topic's (a strategy's first examples are its
    simplest: drawn as one_of, the first batches would hold mostly the first topic), in a
    drawn order."""
    each = max(1, -(-size // len(TOPIC_STRATEGIES)))
    return (st.tuples(*(st.lists(s, min_size=each, max_size=each) for s in TOPIC_STRATEGIES))
            .map(lambda lists: [case for cases in lists for case in cases])
            .flatmap(st.permutations))


# --- parameters -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Declared:
    """What `ros2 param describe` says of one parameter, and its value at the start."""
    name: str
    type: int                       # rcl_interfaces ParameterType
    read_only: bool
    value: object
    low: float | None = None        # the descriptor's range
    high: float | None = None
    choices: tuple[str, ...] = ()   # a string parameter's choices ('one of ...')

    @classmethod
    def of(cls, descriptor, value) -> Declared:
        """From an rcl_interfaces ParameterDescriptor and the parameter's value."""
        low = high = None
        if descriptor.floating_point_range:
            low, high = descriptor.floating_point_range[0].from_value, descriptor.floating_point_range[0].to_value
        choices = ()
        if descriptor.type == STRING and descriptor.additional_constraints.startswith('one of '):
            choices = tuple(descriptor.additional_constraints.split(';')[0][len('one of '):].split(', '))
        return cls(descriptor.name, descriptor.type, descriptor.read_only, value, low, high, choices)


# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING, BYTE_ARRAY, BOOL_ARRAY, INTEGER_ARRAY, DOUBLE_ARRAY, STRING_ARRAY = range(10)
INT64 = (-2**63, 2**63 - 1)
VALUES = {
    BOOL: st.booleans(),
    INTEGER: st.one_of(st.integers(*INT64), st.sampled_from(INT64 + (0, -1))),
    DOUBLE: any_float,
    STRING: st.one_of(text, st.sampled_from(('', 'basic', 'lockstep', 'micromill_9axis', 'x' * 500))),
    BYTE_ARRAY: st.lists(st.binary(min_size=1, max_size=1), max_size=5),
    BOOL_ARRAY: st.lists(st.booleans(), max_size=5),
    INTEGER_ARRAY: st.lists(st.integers(*INT64), max_size=5),
    DOUBLE_ARRAY: st.lists(any_float, max_size=10),
    STRING_ARRAY: st.lists(text, max_size=5),
}


@dataclass(frozen=True)
class ParameterCase:
    """One parameter of a SetParameters request: name, type, value, and what the node must
    answer: 'refused' (with a reason, value unchanged), 'accepted' (read back as set)."""
    node: str
    kind: str
    name: str
    type: int
    value: object
    expect: str

    def message(self):
        from rcl_interfaces.msg import Parameter, ParameterValue
        value = ParameterValue(type=self.type)
        field = {BOOL: 'bool_value', INTEGER: 'integer_value', DOUBLE: 'double_value', STRING: 'string_value',
                 BYTE_ARRAY: 'byte_array_value', BOOL_ARRAY: 'bool_array_value', INTEGER_ARRAY: 'integer_array_value',
                 DOUBLE_ARRAY: 'double_array_value', STRING_ARRAY: 'string_array_value'}.get(self.type)
        if field is not None:
            setattr(value, field, self.value)
        return Parameter(name=self.name, value=value)


# live parameters a valid new value may be given (and is set back after): the others'
# valid values change the motion (servo gains, compensation ramps); they get their own value
FREE = {'trajectory': {'feed': st.floats(1e-4, 0.05)},
        'contour_error': {'estimator': st.sampled_from(('basic', 'shifted', 'compensated'))}}


@st.composite
def parameter_case(draw, node: str, declared: dict[str, Declared], sim_time: bool):
    """A parameter set of `node` with the answer it must get."""
    live = [d for d in declared.values() if not d.read_only]
    read_only = [d for d in declared.values() if d.read_only]
    kinds = ['unknown', 'unset', 'no-op']
    if read_only:
        kinds.append('read-only')
    if live:
        kinds += ['wrong type', 'no-op']
    if any(d.type == DOUBLE for d in live):
        kinds.append('non-finite')
    if any(d.type == DOUBLE and d.low is not None for d in live):
        kinds.append('out of range')
    if any(d.choices for d in live):
        kinds.append('bad choice')
    if sim_time:
        kinds.append('sim time off')
    if node in FREE:
        kinds.append('valid')
    kind = draw(st.sampled_from(kinds))
    if kind == 'unknown':
        # not '': rclpy takes a parameter named '' as declared (test_an_empty_parameter_name_is_refused)
        name_ = draw(st.one_of(text, st.sampled_from(('gains.x_c.speed', 'feed ', 'Feed', 'gains', 'gains.x_c',
                                                      'machine.name', '.', 'qos_overrides', ' ')))
                     .filter(lambda s: s not in declared and s != ''))
        kind_type = draw(st.integers(1, 9))
        return ParameterCase(node, kind, name_, kind_type, draw(VALUES[kind_type]), 'refused')
    if kind == 'unset':
        d = draw(st.sampled_from(sorted(declared.values(), key=lambda d: d.name)))
        return ParameterCase(node, kind, d.name, NOT_SET, None, 'refused')
    if kind == 'read-only':
        d = draw(st.sampled_from(read_only))
        kind_type = draw(st.integers(1, 9))
        return ParameterCase(node, kind, d.name, kind_type, draw(VALUES[kind_type]), 'refused')
    if kind == 'no-op':
        d = draw(st.sampled_from(live or sorted(declared.values(), key=lambda d: d.name)))
        if d.read_only:                # rclpy refuses a read-only one even with its own value
            return ParameterCase(node, 'read-only', d.name, d.type, d.value, 'refused')
        return ParameterCase(node, kind, d.name, d.type, d.value, 'accepted')
    if kind == 'wrong type':
        d = draw(st.sampled_from(live))
        kind_type = draw(st.integers(1, 9).filter(lambda t: t != d.type))
        return ParameterCase(node, kind, d.name, kind_type, draw(VALUES[kind_type]), 'refused')
    if kind == 'non-finite':
        d = draw(st.sampled_from([d for d in live if d.type == DOUBLE]))
        return ParameterCase(node, kind, d.name, DOUBLE, draw(non_finite), 'refused')
    if kind == 'out of range':
        d = draw(st.sampled_from([d for d in live if d.type == DOUBLE and d.low is not None]))
        low = d.low                     # below the descriptor's range
        return ParameterCase(node, kind, d.name, DOUBLE,
                             draw(st.one_of(st.floats(max_value=low, exclude_max=True, allow_infinity=False),
                                            st.sampled_from((-1e308, -5e-324, -1.0))).filter(lambda v: v < low)),
                             'refused')
    if kind == 'bad choice':
        d = draw(st.sampled_from([d for d in live if d.choices]))
        return ParameterCase(node, kind, d.name, STRING, draw(VALUES[STRING].filter(lambda s: s not in d.choices)),
                             'refused')
    if kind == 'sim time off':
        return ParameterCase(node, kind, 'use_sim_time', BOOL, False, 'refused')
    name_, values = draw(st.sampled_from(sorted(FREE[node].items())))
    return ParameterCase(node, kind, name_, declared[name_].type, draw(values), 'accepted')


def plain(value):
    """A parameter value as Python compares it (arrays as lists)."""
    return list(value) if isinstance(value, (tuple, list)) or hasattr(value, 'tolist') else value


def same(a, b) -> bool:
    """Equal, NaN equal to NaN (a refused set must leave a NaN as it was)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return a == b


def check_parameter_answer(node: str, case: ParameterCase, result, expect: str, declared, before, after) -> str:
    """One parameter's answer (rcl_interfaces SetParametersResult) against the oracle's
    `expect`: a refusal has a reason and left the value as it was (`before`, `after`: read
    back around the set), an accepted value reads back. Returns the outcome."""
    outcome = 'accepted' if result.successful else 'refused'
    assert outcome == expect, (node, case, result.reason)
    if not result.successful:
        assert result.reason.strip(), (node, case)
        if case.name in declared:
            assert same(after[case.name], before[case.name]), (node, case, before[case.name], after[case.name])
    elif case.name in declared:
        assert same(after[case.name], plain(case.value)), (node, case, after[case.name])
    return outcome


# --- services -------------------------------------------------------------------------------
TRIGGERS = (contract.HOLD.name, contract.RESUME.name, contract.STOP.name, contract.HOME.name, contract.FREEFORM.name,
            contract.RESET.name)
SWITCHES = (contract.DUAL_STAGE_ENABLE.name, contract.COMPENSATION_ENABLE.name)
service_call = st.one_of(
    st.tuples(st.just('trigger'), st.sampled_from(TRIGGERS)),
    st.tuples(st.just('switch'), st.sampled_from(SWITCHES), st.booleans()),
    st.tuples(st.just('cancel'), st.one_of(st.just('zero'), st.just('active'), st.uuids().map(str)),
              st.one_of(st.just((0, 0)), st.tuples(st.integers(*INT32), st.integers(0, UINT32_MAX)))))
