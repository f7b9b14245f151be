"""Declared node parameters, the ROS side of :mod:`machine_ctrl.parameters`: each table entry
declared with its rcl_interfaces ParameterDescriptor (type, description with the unit, range,
read_only), overrides checked at start, every later set validated by an on-set callback
(refused with the reason `ros2 param set` prints), live values kept current."""
from __future__ import annotations

import sys

from rclpy.node import Node

from machine_ctrl import parameters
from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.errors import ConfigError


class ParameterValues(dict):
    """The typed values of declared parameters, by name and as attributes (`values.feed`);
    live ones are kept current."""

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None


def descriptor(spec: parameters.ParameterSpec, table: parameters.NodeParameters):
    """The rcl_interfaces ParameterDescriptor of a table entry: type, description with the
    unit, range (FloatingPointRange / IntegerRange; an open bound is the closed one in the
    descriptor and refused by the on-set check), read_only unless live; choices and
    conditions in additional_constraints."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
    kind = {parameters.BOOL: ParameterType.PARAMETER_BOOL, parameters.INTEGER: ParameterType.PARAMETER_INTEGER,
            parameters.DOUBLE: ParameterType.PARAMETER_DOUBLE, parameters.STRING: ParameterType.PARAMETER_STRING,
            parameters.DOUBLE_ARRAY: ParameterType.PARAMETER_DOUBLE_ARRAY,
            parameters.STRING_ARRAY: ParameterType.PARAMETER_STRING_ARRAY}[spec.type]
    result = ParameterDescriptor(name=spec.name, type=kind,
                                 description=spec.description + (f' [{spec.unit}]' if spec.unit else ''),
                                 additional_constraints=parameters.constraint_text(table, spec),
                                 read_only=spec.read_only)
    if spec.numeric and (spec.low is not None or spec.high is not None):
        if spec.type == parameters.INTEGER:
            big = 2 ** 63 - 1
            result.integer_range = [IntegerRange(
                from_value=int(spec.low) if spec.low is not None else -big - 1,
                to_value=int(spec.high) if spec.high is not None else big, step=1)]
        else:
            big = sys.float_info.max
            result.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low) if spec.low is not None else -big,
                to_value=float(spec.high) if spec.high is not None else big, step=0.0)]
    return result


class _Declared:
    """What declare_parameters keeps per node: the specs and checks declared, the values,
    the hooks of live parameters."""

    def __init__(self, node: Node):
        self.node = node
        self.values = ParameterValues()
        self.tables: dict[str, parameters.NodeParameters] = {}     # name -> its table
        self.on_change: dict[str, object] = {}
        node.add_on_set_parameters_callback(self.on_set)
        node.add_post_set_parameters_callback(self.after_set)

    def on_set(self, params):
        from rcl_interfaces.msg import SetParametersResult
        by_table: dict[int, tuple] = {}
        for param in params:
            table = self.tables.get(param.name)
            if table is None:               # not ours (use_sim_time, ...) or being declared
                continue
            by_table.setdefault(id(table), (table, {}))[1][param.name] = param.value
        for table, changed in by_table.values():
            names = set(changed) | {n for c in table.checks if set(c.names) & set(changed) for n in c.names}
            values = {n: changed.get(n, self.values.get(n)) for n in names if n in changed or n in self.values}
            problems = parameters.check_values(table, values)
            if problems:
                return SetParametersResult(successful=False, reason=_problem_text(problems))
        return SetParametersResult(successful=True)

    def after_set(self, params) -> None:
        for param in params:
            if param.name in self.tables and param.name in self.values:
                self.values[param.name] = _plain(param.value)
                hook = self.on_change.get(param.name)
                if hook is not None:
                    hook(self.values[param.name])


def _plain(value):
    import array
    return list(value) if isinstance(value, (array.array, tuple)) else value


def _problem_text(problems) -> str:
    return '; '.join(f'{name}: {reason}' for name, reason in problems)


def declare_parameters(node: Node, table, defaults: dict | None = None, names=None,
                       on_change: dict | None = None) -> ParameterValues:
    """Declare the parameters of `table` (a machine_ctrl.parameters.NodeParameters, or a
    tuple of ParameterSpec) on `node` with descriptors built from it, and return the typed
    values of every parameter of the node declared so far.

    `names`: only these (a node may declare in steps when a default depends on another
    value); parameters the node has already declared are skipped. `defaults`: the defaults
    the table leaves to the node (default None). Every override is checked against the
    table first: a bad one ends the node with one line on the log (exit 2). Later sets
    are refused with the reason (read-only ones by rclpy); a live parameter needs an
    `on_change[name](value)` hook, called after each accepted set."""
    if not isinstance(table, parameters.NodeParameters):
        table = parameters.NodeParameters(node.get_name(), tuple(table))
    state = getattr(node, '_machine_ctrl_parameters', None)
    if state is None:
        state = _Declared(node)
        node._machine_ctrl_parameters = state
    defaults, on_change = defaults or {}, on_change or {}
    wanted = [spec for spec in table if (names is None or spec.name in names) and spec.name not in state.values]
    for spec in wanted:
        if spec.live != (spec.name in on_change):
            raise ValueError(f'{spec.name}: a live parameter needs an on_change hook, a read-only one has none')
    default_of = {spec.name: spec.default if spec.default is not None else parameters.coerce(spec, defaults[spec.name])
                  for spec in wanted if spec.default is not None or spec.name in defaults}
    given = {}
    for spec in wanted:
        if spec.name in node._parameter_overrides:          # noqa: SLF001 - rclpy keeps them there
            given[spec.name] = _plain(node._parameter_overrides[spec.name].value)
        elif spec.name in default_of:
            given[spec.name] = default_of[spec.name]
        else:
            raise ValueError(f'{spec.name}: the node must supply the default ({spec.default_text})')
    known = {**{n: v for n, v in state.values.items() if n in table.names}, **given}
    problems = [(n, r) for n, r in parameters.check_values(table, known) if n in given or n not in state.values]
    if problems:
        what = f'parameter {problems[0][0]}: {problems[0][1]}' if len(problems) == 1 else \
            f'parameters: {_problem_text(problems)}'
        node.get_logger().fatal(what)
        raise SystemExit(2)
    for spec in wanted:
        value = node.declare_parameter(spec.name, default_of[spec.name], descriptor(spec, table)).value
        state.values[spec.name] = _plain(value)
        state.tables[spec.name] = table
        if spec.live:
            state.on_change[spec.name] = on_change[spec.name]
    return state.values


def machine_parameter(node: Node) -> MachineConfig:
    """The `machine` parameter (name or YAML path), loaded; a bad config ends the node with
    one line on the log."""
    name = declare_parameters(node, (parameters.MACHINE,)).machine
    try:
        return load_machine(name)
    except ConfigError as exc:
        node.get_logger().fatal(str(exc))
        raise SystemExit(2) from None
