"""The parameters of every node, declared once, as data (in the spirit of ros2_controllers'
generate_parameter_library): name, type, default, unit, range, read-only or live, and a
description. ROS-free, beside :mod:`machine_ctrl.contract`.

From these tables

* each node declares its parameters with rcl_interfaces ParameterDescriptors (type,
  description with the unit, FloatingPointRange / IntegerRange, read_only) and validates
  every value — overrides at start (a bad one ends the node with one line, exit 2) and
  every later set (refused with the reason): :func:`machine_ctrl.ros.node_parameters.declare_parameters`;
* node specs for bringup are typed data (:class:`machine_ctrl.ros.graph.NodeSpec` coerces
  and checks its values here, and writes them to ROS parameter files);
* the README table "Node parameters" is printed by ``python -m machine_ctrl.parameters``
  (and `test/test_parameters.py` checks the README against the tables).

A value is never clamped: it is accepted as given or refused with the reason. Read-only
parameters are read once at start; a live one takes effect while the node runs (its
description says when and why that is safe) and the node publishes the value in effect in
its /diagnostics status. A *template* entry (``gains.<axis>.<gain>``) stands for parameters
the node declares per item (each with its own descriptor); its table row describes them all.
Nodes on the simulated clock (``sim_time``) refuse ``use_sim_time`` false (:data:`SIM_TIME_REASON`).
"""
from __future__ import annotations

import array
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from machine_ctrl import contract
from machine_ctrl.model.config import DEFAULT_MACHINE

# ROS parameter types (rcl_interfaces/ParameterType names, lower case)
BOOL, INTEGER, DOUBLE, STRING = 'bool', 'integer', 'double', 'string'
DOUBLE_ARRAY, STRING_ARRAY = 'double_array', 'string_array'
TYPES = (BOOL, INTEGER, DOUBLE, STRING, DOUBLE_ARRAY, STRING_ARRAY)


@dataclass(frozen=True)
class ParameterSpec:
    """One declared parameter. `default` None: the node supplies it (it depends on the
    machine), `default_text` says what it is. `low`/`high` bound numbers (closed, or open
    with `low_open`/`high_open`); `choices` lists the allowed strings; `required`: a
    string that must not be empty. `constraint`: the allowed values in words when the
    bounds alone do not say it. `template`: the name has <placeholders> (see the module)."""
    name: str
    type: str
    default: object
    unit: str = ''
    description: str = ''
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[str, ...] = ()
    required: bool = False
    live: bool = False
    default_text: str = ''
    constraint: str = ''
    template: bool = False

    def __post_init__(self):
        if self.type not in TYPES:
            raise ValueError(f'{self.name}: unknown parameter type {self.type!r}')
        if self.default is not None and (problem := type_problem(self.type, self.default)):
            raise ValueError(f'{self.name}: default {problem}')
        if self.default is None and not self.default_text:
            raise ValueError(f'{self.name}: a default given by the node needs default_text')

    @property
    def read_only(self) -> bool:
        return not self.live

    @property
    def numeric(self) -> bool:
        return self.type in (INTEGER, DOUBLE)

    def matches(self, name: str) -> bool:
        """Whether `name` is this parameter (or, for a template, one of its instances)."""
        if not self.template:
            return name == self.name
        pattern = '\\.'.join('[^.]+' if re.fullmatch(r'<[^<>]+>', part) else re.escape(part)
                              for part in self.name.split('.'))
        return re.fullmatch(pattern, name) is not None


@dataclass(frozen=True)
class Check:
    """A condition between parameters of one node: `test(values)` -> reason or None,
    reported for parameter `name` (the values hold every name in `names`)."""
    name: str
    names: tuple[str, ...]
    test: Callable[[Mapping], str | None]
    text: str                         # what it requires, for descriptors and the README


@dataclass(frozen=True)
class NodeParameters:
    """The parameter table of one node executable."""
    executable: str                   # e.g. hw_sim_node
    parameters: tuple[ParameterSpec, ...]
    checks: tuple[Check, ...] = field(default=())
    sim_time: bool = False            # the node runs on hw_sim's clock: use_sim_time true, fixed

    def __iter__(self):
        return iter(self.parameters)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def spec(self, name: str) -> ParameterSpec:
        """The entry of `name`: its own, or the template it is an instance of."""
        for p in self.parameters:
            if p.name == name:
                return p
        for p in self.parameters:
            if p.template and p.matches(name):
                return p
        raise KeyError(f'{self.executable}: no parameter {name!r}')

    def defaults(self) -> dict:
        """The defaults that do not depend on the machine."""
        return {p.name: p.default for p in self.parameters if p.default is not None and not p.template}


# --- validation -----------------------------------------------------------------------

def _kind(value) -> str:
    if isinstance(value, bool):
        return 'bool'
    if isinstance(value, int):
        return 'integer'
    if isinstance(value, float):
        return 'double'
    if isinstance(value, str):
        return 'string'
    if isinstance(value, (list, tuple, array.array)):
        return 'array'
    return type(value).__name__


def type_problem(kind: str, value) -> str | None:
    """Why `value` is not of ROS parameter type `kind`, or None."""
    if kind == BOOL and isinstance(value, bool):
        return None
    if kind == INTEGER and isinstance(value, int) and not isinstance(value, bool):
        return None
    if kind == DOUBLE and isinstance(value, float):
        return None
    if kind == STRING and isinstance(value, str):
        return None
    if kind in (DOUBLE_ARRAY, STRING_ARRAY) and isinstance(value, (list, tuple, array.array)):
        item = float if kind == DOUBLE_ARRAY else str
        if all(isinstance(v, item) for v in value):
            return None
        return f'must be a list of {"floating-point numbers" if item is float else "strings"}, got {_show(value)}'
    wanted = {BOOL: 'true or false', INTEGER: 'an integer', DOUBLE: 'a floating-point number (e.g. 1.0, not 1)',
              STRING: 'a string', DOUBLE_ARRAY: 'a list of floating-point numbers',
              STRING_ARRAY: 'a list of strings'}[kind]
    return f'must be {wanted}, got {_kind(value)} {_show(value)}'


def _show(value) -> str:
    if isinstance(value, array.array):
        value = list(value)
    return repr(value)


def range_text(spec: ParameterSpec) -> str:
    """The allowed values in words: the spec's `constraint`, else `(0, 1]`, `>= 1`, `one of
    a, b`, `non-empty`, or ''."""
    return spec.constraint or bounds_text(spec)


def bounds_text(spec: ParameterSpec) -> str:
    """The allowed values by the spec's bounds, choices or `required`, in words."""
    if spec.choices:
        return 'one of ' + ', '.join(spec.choices)
    if spec.required:
        return 'non-empty'
    lo, hi = spec.low, spec.high
    if lo is not None and hi is not None:
        return f'{"(" if spec.low_open else "["}{lo:g}, {hi:g}{")" if spec.high_open else "]"}'
    if lo is not None:
        return f'{">" if spec.low_open else ">="} {lo:g}'
    if hi is not None:
        return f'{"<" if spec.high_open else "<="} {hi:g}'
    if spec.type in (DOUBLE, DOUBLE_ARRAY):
        return 'finite'
    return ''


def _choice_words(choices) -> str:
    return choices[0] if len(choices) == 1 else f'{", ".join(choices[:-1])} or {choices[-1]}'


def validate(spec: ParameterSpec, value) -> str | None:
    """Why `value` is not allowed for `spec` (without the parameter name), or None."""
    if (problem := type_problem(spec.type, value)) is not None:
        return problem
    if spec.type in (DOUBLE, DOUBLE_ARRAY):
        values = [value] if spec.type == DOUBLE else list(value)
        if not all(math.isfinite(v) for v in values):
            return f'must be finite, got {_show(value)}'
    if spec.numeric:
        too_low = spec.low is not None and (value <= spec.low if spec.low_open else value < spec.low)
        too_high = spec.high is not None and (value >= spec.high if spec.high_open else value > spec.high)
        if too_low or too_high:
            unit = f' {spec.unit}' if spec.unit else ''
            words = bounds_text(spec)
            return f'must be {"in " if words[0] in "[(" else ""}{words}{unit}, got {_show(value)}'
    if spec.choices and value not in spec.choices:
        return f'must be {_choice_words(spec.choices)}, got {value!r}'
    if spec.required and not value:
        return f'missing: {spec.description}'
    return None


def check_values(table: NodeParameters, values: Mapping) -> list[tuple[str, str]]:
    """(name, reason) of every value in `values` that its spec refuses, then of every
    check of the table whose parameters are all in `values`."""
    problems = []
    for name, value in values.items():
        try:
            spec = table.spec(name)
        except KeyError:
            problems.append((name, f'not a parameter of {table.executable}'))
            continue
        if (reason := validate(spec, value)) is not None:
            problems.append((name, reason))
    if not problems:
        for check in table.checks:
            if all(n in values for n in check.names) and (reason := check.test(values)) is not None:
                problems.append((check.name, reason))
    return problems


def coerce(spec: ParameterSpec, value):
    """Python data -> the declared type, exactly (int -> float for doubles, tuples ->
    lists); anything else is returned as is (and refused by :func:`validate`)."""
    if isinstance(value, array.array):
        value = list(value)
    if spec.type == DOUBLE and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if spec.type == DOUBLE_ARRAY and isinstance(value, (list, tuple)):
        return [float(v) if isinstance(v, int) and not isinstance(v, bool) else v for v in value]
    if spec.type == STRING_ARRAY and isinstance(value, tuple):
        return list(value)
    return value


# --- the tables ---------------------------------------------------------------------------

SIM_TIME_REASON = (f"this node runs on hw_sim's simulated clock (topic {contract.CLOCK.name}, design.md "
                   '"Time"); it cannot be switched off')

MACHINE = ParameterSpec('machine', STRING, DEFAULT_MACHINE, description='machine name (config/machines/) or path of its YAML file')
BELIEF = ParameterSpec('belief', STRING_ARRAY, [''], description="files of the controllers' values (`machine-ctrl "
                       "identify --out`) merged over the machine config's, in order; empty: the config's own. hw_sim "
                       "keeps simulating the config's plant (README \"Truth and belief\")")
INPUT_TIMEOUT = ParameterSpec('input_timeout', DOUBLE, 0.5, 's', 'wall time to wait for a missing reference row or '
                              'offsets once the stream has started, then go on without', low=0.0, low_open=True)
# assumed: 100 rows (21.6 KB for 9 axes). Every message a process sends over shared memory
# takes a buffer of its Fast DDS segment (512 KB by default, the size rmw_fastrtps gives it
# under ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), and a reader killed while it held one keeps
# it taken for good. With 500 rows (108 KB) the trajectory node, the compensation node it
# fed killed and started again, then sent no chunk to any reader (test_faults_compensation:
# 6 runs in 33 stuck, a new reader of /trajectory/reference heard nothing, a new trajectory
# process was heard at once); with 100 rows, 0 in 20 (README "Faults", 2026-12-08).
CHUNK_STEPS = ParameterSpec('chunk_steps', INTEGER, 100, 'steps', 'rows per reference message', low=1)
LOOKAHEAD_STEPS = ParameterSpec('lookahead_steps', INTEGER, 3000, 'steps', 'rows kept streamed ahead of the sim time',
                                low=1)


def _at_least(name: str, other: str, factor: int):
    def test(values):
        if values[name] < factor * values[other]:
            times = f'{factor} x ' if factor != 1 else ''
            return f'must be >= {times}{other} ({factor * values[other]}), got {values[name]}'
        return None
    return Check(name, (name, other), test, f'>= {"%d x " % factor if factor != 1 else ""}{other}')


def _history_covers_lookahead(values) -> str | None:
    """A reader that joins late gets the last contract.REFERENCE_QOS.depth chunks (transient
    local): they must hold the rows from the sim step to the end of the stream."""
    depth = contract.REFERENCE_QOS.depth
    if values['lookahead_steps'] + values['chunk_steps'] > depth * values['chunk_steps']:
        return (f'must be <= {depth - 1} x chunk_steps ({(depth - 1) * values["chunk_steps"]}: a late reader gets '
                f'the last {depth} chunks), got {values["lookahead_steps"]}')
    return None


HISTORY_COVERS_LOOKAHEAD = Check('lookahead_steps', ('lookahead_steps', 'chunk_steps'), _history_covers_lookahead,
                                 f'<= {contract.REFERENCE_QOS.depth - 1} x chunk_steps')


def _facts_problem(facts) -> str | None:
    for fact in facts:
        if fact:
            try:
                contract.session_fact(fact)
            except ValueError as exc:
                return str(exc)
    return None


def _window_needs_lockstep(values):
    if values['recorder_window'] > 0 and values['mode'] != 'lockstep':
        return f'needs mode lockstep (0 with mode {values["mode"]}), got {values["recorder_window"]}'
    return None


def _waiting_needs_a_window(values) -> str | None:
    if values['wait_for_recorder'] and values['recorder_window'] <= 0:
        return f'needs recorder_window > 0, got {values["recorder_window"]}'
    return None


HW_SIM = NodeParameters('hw_sim_node', (
    MACHINE,
    ParameterSpec('mode', STRING, 'lockstep', description='lockstep: step k -> k+1 once every axis has its '
                  'command; paced: step on the wall clock', choices=('lockstep', 'paced')),
    ParameterSpec('real_time_factor', DOUBLE, 0.1, description='paced mode: sim time per wall time',
                  low=0.0, high=1.0, low_open=True),
    # assumed: 5 s, above the transport's own stall of a healthy process after a reader's death
    # (up to 2.4 s measured; contract.LIVELINESS_LEASE says why): a dead or stopped node is
    # still detected, a stalled publisher is not taken for one
    ParameterSpec('command_timeout', DOUBLE, 5.0, 's', 'wall time before the machine faults: a command missing '
                  '(lock-step), an axis without any command (paced), hw_sim itself not run (both)', low=0.0,
                  low_open=True),
    ParameterSpec('republish_period', DOUBLE, 0.2, 's', 'lock-step: wall time between re-sends of the state '
                  'waited on', low=0.0, low_open=True),
    ParameterSpec('clock_decimation', INTEGER, 10, 'steps', f'publish {contract.CLOCK.name} every N steps', low=1),
    ParameterSpec('ground_truth_decimation', INTEGER, 10, 'steps', 'publish ground truth every N steps '
                  '(0: never)', low=0),
    ParameterSpec('initial_position', DOUBLE_ARRAY, None, 'm, rad', 'axis positions at start, in axis order, '
                  'inside the strokes', default_text="the machine's home"),
    ParameterSpec('min_subscribers', INTEGER, 0, description=f'hold at step 0 until {contract.JOINT_STATES.name} has this many '
                  'subscribers', low=0),
    ParameterSpec('recorder_window', INTEGER, 0, 'steps', 'lock-step: steps hw_sim may run ahead of a '
                  "recorder's progress (0: off)", low=0),
    ParameterSpec('wait_for_recorder', BOOL, False, description='lock-step: hold at step 0 until a recorder has '
                  'reported its progress (and then until it has state 0)'),
), checks=(Check('recorder_window', ('recorder_window', 'mode'), _window_needs_lockstep, '0 unless mode is lockstep'),
           Check('wait_for_recorder', ('wait_for_recorder', 'recorder_window'), _waiting_needs_a_window,
                 'false unless recorder_window > 0')))

SERVO = NodeParameters('servo_node', (
    MACHINE,
    BELIEF,
    ParameterSpec('axes', STRING_ARRAY, None, description='axes this node controls (machine axis names)',
                  default_text='every controlled axis', constraint='controlled axes of the machine, each once'),
    ParameterSpec('feedforward', BOOL, True, description='velocity, acceleration and friction feed-forward; '
                  'live: switched at the first step whose reference is at rest on every axis of the node '
                  '(under motion a switch steps the command by (K_s + m_e lambda) v_r + m_e a_r: 1.4-4.4 V of the '
                  "micromill's 5 V at 10 mm/s)", live=True),
    ParameterSpec('gains.<axis>.<gain>', DOUBLE, None, "the gain's (SI)",
                  "live gains of each axis's law (a new set of the law's parameters, applied between two steps): "
                  'sliding_mode bandwidth, gain, adaptation (the command moves in proportion to the tracking error; '
                  'refused unless T (K_s/m_e + lambda) < 1); ppi position_gain, velocity_gain, velocity_integral_gain '
                  '(the integral is rescaled: bumpless); lead_lag none (its filter states belong to their coefficients); '
                  'pid proportional, integral, derivative (the integrator holds K_i * integral: bumpless); h2 none (each weight '
                  'changes the whole design); position_command velocity_lead (a feed-forward term without state); lqg none '
                  '(each weight changes the whole design)',
                  default_text="the machine config's (axes.<axis>.control.<law>), the belief files' over it",
                  constraint="as in the machine config: > 0 or >= 0; the law's conditions", live=True, template=True),
    ParameterSpec('contour_control', BOOL, False, description="the machine's cross-coupled contour control "
                  '(machine config contour_control; README "Contour control"); live: on from the next step, the '
                  'correction fading in from zero; off: it fades out (time constant fade)', live=True,
                  constraint='true only on the node holding every coupled axis of a machine with a contour_control '
                  'section'),
    ParameterSpec('wait_for_offsets', BOOL, None, description='the axes a dual-stage coupling offsets (its fine '
                  'axes; with mid-ranging its coarse axes too) wait for '
                  f'{contract.DUAL_STAGE_OFFSETS.name} each step (no effect without such axes)',
                  default_text='true when the node has such axes'),
    INPUT_TIMEOUT,
), sim_time=True)

DUAL_STAGE = NodeParameters('dual_stage_node', (
    MACHINE,
    ParameterSpec('dual_stage', BOOL, True, description='dual-stage coupling on (off: every offset zero at once, '
                  'the mid-ranging take-over too); live: from the next step, the fine reference moves by the coarse '
                  'tracking error, inside the fine stroke; '
                  f'{contract.DUAL_STAGE_ENABLE.name} sets this parameter', live=True),
    INPUT_TIMEOUT,
), sim_time=True)

REFERENCE = NodeParameters('reference_node', (
    MACHINE,
    ParameterSpec('contour', STRING, 'circle', description='test contour to stream',
                  choices=('circle', 'square', 'hold')),
    CHUNK_STEPS,
    LOOKAHEAD_STEPS,
), checks=(_at_least('lookahead_steps', 'chunk_steps', 1), HISTORY_COVERS_LOOKAHEAD), sim_time=True)

TRAJECTORY = NodeParameters('trajectory_node', (
    MACHINE,
    ParameterSpec('feed', DOUBLE, 0.01, 'm/s', 'process feed limit of tool paths; live: from the next path',
                  low=0.0, low_open=True, live=True),
    CHUNK_STEPS,
    LOOKAHEAD_STEPS,
    ParameterSpec('output_topic', STRING, contract.REFERENCE.name, description='where the reference chunks go '
                  f'({contract.TRAJECTORY_REFERENCE.name} when compensation sits between)', required=True),
    # contract.STALL_LIMIT: the default and why the lease bounds it
    ParameterSpec('stall_limit', DOUBLE, contract.STALL_LIMIT, 's', 'wall time its own process may not run while a '
                  'goal is under way: a longer gap aborts the goal (trajectory stalled); at most the liveliness '
                  f'lease ({contract.LIVELINESS_LEASE:g} s), after which every client\'s reader has run out of it; '
                  'live: from its next check', low=0.0, low_open=True, high=contract.LIVELINESS_LEASE, live=True),
    # the freeform cut that contract.FREEFORM starts (trajectory/freeform.py; Ding Ch. 8): read at the call
    ParameterSpec('freeform.surface', STRING, 'sinusoidal_grid', description='surface: sinusoidal_grid (Ding '
                  'Table 8-5), beam_integrator (Table 8-4), micro_lens_array (Table 8-3) or the path of a CSV '
                  f'surface table (x, y, height in m); live: read by {contract.FREEFORM.name}', required=True,
                  live=True),
    ParameterSpec('freeform.spindle_speed', DOUBLE, 2 * math.pi, 'rad/s', 'spindle speed (default 60 rpm, Ding '
                  f'Table 8-5); live: read by {contract.FREEFORM.name}', low=0.0, low_open=True, live=True),
    ParameterSpec('freeform.feed_per_rev', DOUBLE, 5e-6, 'm', 'radial feed per revolution, towards the centre '
                  f'(Ding Table 8-5); live: read by {contract.FREEFORM.name}', low=0.0, live=True),
    ParameterSpec('freeform.start_radius', DOUBLE, 25e-3, 'm', 'radius where the cut starts (the 50 mm workpiece '
                  f'of Ding section 8.5.3); live: read by {contract.FREEFORM.name}', low=0.0, live=True),
    ParameterSpec('freeform.duration', DOUBLE, 0.1, 's', f'length of the cut; live: read by {contract.FREEFORM.name}',
                  low=0.0, low_open=True, live=True),
    ParameterSpec('freeform.start_angle', DOUBLE, 0.0, 'rad', f'spindle angle where the cut starts; live: read by '
                  f'{contract.FREEFORM.name}', live=True),
    ParameterSpec('freeform.lead', DOUBLE, 0.02, 's', 'time over which the fast axis lands on the surface before the '
                  f'cut and lifts off after it; live: read by {contract.FREEFORM.name}', low=0.0, high=1.0, live=True),
), checks=(_at_least('lookahead_steps', 'chunk_steps', 2), HISTORY_COVERS_LOOKAHEAD), sim_time=True)

COMPENSATION = NodeParameters('compensation_node', (
    MACHINE,
    ParameterSpec('model', STRING, '', description='geometric error model YAML (machine-ctrl fit-errors --out)',
                  required=True),
    ParameterSpec('enabled', BOOL, True, description='geometric compensation on; live: from the next chunk, '
                  f'ramped in or out over 0.1 s; {contract.COMPENSATION_ENABLE.name} sets this parameter', live=True),
    ParameterSpec('input_topic', STRING, contract.TRAJECTORY_REFERENCE.name, description='uncompensated '
                  'reference chunks', required=True),
    ParameterSpec('output_topic', STRING, contract.REFERENCE.name, description='compensated reference chunks',
                  required=True),
))

CONTOUR_ERROR = NodeParameters('contour_error_node', (
    MACHINE,
    ParameterSpec('estimator', STRING, 'compensated', description='contour error estimator (README "Contour '
                  'error"); live: from the next step (the estimators share their state, only the formula changes)',
                  choices=('basic', 'shifted', 'compensated'), live=True),
), sim_time=True)

RECORDER = NodeParameters('recorder_node', (
    ParameterSpec('output', STRING, '', description='bag directory to create (absent or empty)', required=True),
    ParameterSpec('topics', STRING_ARRAY, [''], description='topics (NAME or NAME:pkg/msg/Type); empty: all '
                  f'but {contract.ROSOUT}, {contract.PARAMETER_EVENTS} and its own {contract.RECORDER_PROGRESS.name}'),
    ParameterSpec('machine', STRING, '', description='machine name or YAML path stored with the bag (empty: none)'),
    ParameterSpec('discovery_period', DOUBLE, 0.2, 's', 'wall time between topic discoveries',
                  low=0.0, low_open=True),
    ParameterSpec('duration', DOUBLE, 0.0, 's', 'wall time to record (0: until stopped)', low=0.0),
    ParameterSpec('start_streams', INTEGER, 0, description=f'subscribe {contract.JOINT_STATES.name} only once this '
                  'many answer streams (each publisher of ' + ' and '.join(t.name for t in contract.STEP_ANSWERS) +
                  ') have sent: hw_sim, holding step 0 for this recorder (min_subscribers), then starts with '
                  'every answer reaching the bag (0: subscribe at once)', low=0),
    ParameterSpec('session', STRING_ARRAY, [''], description="facts of the recorded graph, KEY=VALUE each, kept in "
                  "the bag's custom_data as machine_ctrl.session.KEY (bringup and the launch file give hw_sim's mode "
                  "and real-time factor and the servos' belief files; empty: none)"),
), checks=(Check('start_streams', ('start_streams', 'topics'),
                 lambda values: (f'needs every topic recorded (topics empty), got {values["start_streams"]}'
                                 if values['start_streams'] and any(values['topics']) else None),
                 '0 unless topics is empty'),
           Check('session', ('session',), lambda values: _facts_problem(values['session']), 'each KEY=VALUE'),))

REPLAY = NodeParameters('replay_node', (
    ParameterSpec('bag', STRING, '', description='bag directory or .mcap file', required=True),
    ParameterSpec('rate', DOUBLE, 1.0, description='factor on the recorded timing', low=0.0, low_open=True),
    ParameterSpec('topics', STRING_ARRAY, [''], description='topics to replay; empty: all'),
    ParameterSpec('start_offset', DOUBLE, 0.0, 's', 'time into the bag to start at', low=0.0),
    ParameterSpec('loop', BOOL, False, description='replay again and again'),
    ParameterSpec('wait_for_subscribers', INTEGER, 0, description='start once every publisher has this many '
                  'matched subscriptions', low=0),
    ParameterSpec('wait_timeout', DOUBLE, 30.0, 's', 'wall time to wait for them', low=0.0),
))

VIEW = NodeParameters('view_node', (
    MACHINE,
    # assumed: this computer only; a viewer on another one is a deliberate choice (0.0.0.0)
    ParameterSpec('host', STRING, '127.0.0.1', description='address the Foxglove WebSocket server listens on',
                  required=True),
    # Foxglove's own default port, which its "Open connection" dialog proposes
    ParameterSpec('port', INTEGER, 8765, description='TCP port of the Foxglove WebSocket server (0: any free port, '
                  'logged)', low=0, high=65535),
    # assumed: 50 Hz, what a plot panel redraws smoothly; the view then takes 50 messages a
    # second of each per-step stream whatever the graph's rate (bench/view_cost.py)
    ParameterSpec('sample_rate', DOUBLE, 50.0, 'Hz', 'wall rate at which the newest message of each per-step '
                  'stream is taken and forwarded', low=0.0, low_open=True, high=1000.0),
))

TABLES = (HW_SIM, SERVO, DUAL_STAGE, TRAJECTORY, REFERENCE, COMPENSATION, CONTOUR_ERROR, RECORDER, REPLAY, VIEW)


def table(executable: str) -> NodeParameters:
    """The table of a node executable (e.g. 'servo_node')."""
    for t in TABLES:
        if t.executable == executable:
            return t
    raise KeyError(f'no parameter table for {executable!r}')


# --- the README table -------------------------------------------------------------------------

def default_text(spec: ParameterSpec) -> str:
    if spec.default is None:
        return spec.default_text
    value = spec.default
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return value if value else "''"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(repr(v) for v in value) + ']'
    return str(value)


def constraint_text(table_: NodeParameters, spec: ParameterSpec) -> str:
    """The range column: the spec's range and the table's checks on the parameter."""
    parts = [range_text(spec)] + [c.text for c in table_.checks if c.name == spec.name]
    return '; '.join(p for p in parts if p)


README_HEADER = ('| executable | parameter | type | default | unit | range | set | description |\n'
                 '|---|---|---|---|---|---|---|---|')


def readme_rows(table_: NodeParameters) -> list[tuple[str, ...]]:
    """One row per parameter: the README columns, as plain text."""
    return [(table_.executable, p.name, p.type, default_text(p), p.unit, constraint_text(table_, p),
             'live' if p.live else 'read-only', p.description) for p in table_.parameters]


def _cell(text: str, code: bool) -> str:
    text = text.replace('|', '\\|')
    return f'`{text}`' if code and text else text


def markdown() -> str:
    """The README table "Node parameters" (python -m machine_ctrl.parameters prints it)."""
    lines = [README_HEADER]
    for t in TABLES:
        for spec, row in zip(t.parameters, readme_rows(t)):
            codes = (True, True, False, spec.default is not None, False, False, False, False)
            lines.append('| ' + ' | '.join(_cell(text, code) for text, code in zip(row, codes)) + ' |')
    return '\n'.join(lines)


if __name__ == '__main__':
    print(markdown())
