"""Declared node parameters, the ROS side of :mod:`machine_ctrl.parameters`: each table entry
declared with its rcl_interfaces ParameterDescriptor (type, description with the unit, range,
read_only), overrides checked at start, every later set validated by an on-set callback
(refused with the reason `ros2 param set` prints), live values kept current and handed to
the node's hooks after each accepted set.

Also here: the servo's live law gains as parameters (:func:`gain_parameters`, one per axis
and live gain of its law, ``gains.<axis>.<gain>``), the sim-time rule (a node that runs on
the simulated clock refuses ``use_sim_time`` false, at start and later), and the shipped ROS
parameter files of the bringup graph (``config/params/<machine>.yaml``,
:func:`params_file_text`; ``python -m machine_ctrl.ros.node_parameters --write DIR`` writes
them, ``--check DIR`` compares).
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from rclpy.node import Node

from machine_ctrl import contract, parameters
from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.errors import ConfigError

USE_SIM_TIME = 'use_sim_time'


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
    the hooks of live parameters, and whether the node runs on the simulated clock (its
    use_sim_time when it first declared: node_common.use_sim_time sets it before)."""

    def __init__(self, node: Node):
        self.node = node
        self.values = ParameterValues()
        self.tables: dict[str, parameters.NodeParameters] = {}     # name -> its table
        self.on_change: dict[str, object] = {}
        self.sim_time = node.has_parameter(USE_SIM_TIME) and node.get_parameter(USE_SIM_TIME).value is True
        node.add_on_set_parameters_callback(self.on_set)
        node.add_post_set_parameters_callback(self.after_set)
        refuse_unknown_types(node)
        if self.sim_time:
            from rcl_interfaces.msg import ParameterDescriptor, ParameterType
            node.set_descriptor(USE_SIM_TIME, ParameterDescriptor(
                name=USE_SIM_TIME, type=ParameterType.PARAMETER_BOOL, additional_constraints='true',
                description=parameters.SIM_TIME_REASON))

    def sim_time_problem(self, value) -> str | None:
        if self.sim_time and value is not True:
            shown = str(value).lower() if isinstance(value, bool) else repr(value)
            return f'{USE_SIM_TIME}: {parameters.SIM_TIME_REASON}, got {shown}'
        return None

    def on_set(self, params):
        from rcl_interfaces.msg import SetParametersResult
        by_table: dict[int, tuple] = {}
        for param in params:
            if not param.name:              # rclpy 7.1 lets '' through its undeclared-name check
                return SetParametersResult(successful=False, reason='a parameter needs a name (got an empty one)')
            if param.name == USE_SIM_TIME and (problem := self.sim_time_problem(param.value)) is not None:
                return SetParametersResult(successful=False, reason=problem)
            table = self.tables.get(param.name)
            if table is None:               # not ours (use_sim_time, ...) or being declared
                continue
            by_table.setdefault(id(table), (table, {}))[1][param.name] = _plain(param.value)
        for table, changed in by_table.values():
            names = set(changed) | {n for c in table.checks if set(c.names) & set(changed) for n in c.names}
            values = {n: changed.get(n, self.values.get(n)) for n in names if n in changed or n in self.values}
            problems = parameters.check_values(table, values)
            if problems:
                return SetParametersResult(successful=False, reason=_problem_text(problems))
        return SetParametersResult(successful=True)

    def after_set(self, params) -> None:
        """Every accepted value first (each change logged: what a controller's operator and
        a failure's reader want to know), then the hooks (a hook may read several values:
        gains of one axis set together)."""
        ours = [param.name for param in params if param.name in self.tables and param.name in self.values]
        for param in params:
            if param.name in ours:
                before, self.values[param.name] = self.values[param.name], _plain(param.value)
                if before != self.values[param.name]:
                    self.node.get_logger().info(f'parameter {param.name}: {before!r} -> {self.values[param.name]!r}')
        for name in ours:
            hook = self.on_change.get(name)
            if hook is not None:
                hook(self.values[name])


def refuse_unknown_types(node: Node) -> None:
    """A ParameterValue's type is a uint8, and 10..255 name no ParameterType: rclpy 7.1's
    set_parameters services raise on one (Parameter.from_parameter_msg) and answer nothing,
    the caller waiting for ever. Here such a parameter is refused with the reason: on
    set_parameters on its own, the request's others handled as rclpy handles them (each
    through rclpy's own callback); on set_parameters_atomically the whole request, nothing set."""
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.parameter import Parameter

    known = {kind.value for kind in Parameter.Type}

    def refusal(param) -> SetParametersResult:
        return SetParametersResult(successful=False, reason=f'parameter {param.name!r}: type {param.value.type} is '
                                                            f'not a ParameterType (0-{max(known)})')

    def one_by_one(rclpy_callback):
        def callback(request, response):
            for param in request.parameters:
                if param.value.type in known:
                    single = type(request)(parameters=[param])
                    response.results.extend(rclpy_callback(single, type(response)()).results)
                else:
                    response.results.append(refusal(param))
            return response
        return callback

    def all_or_none(rclpy_callback):
        def callback(request, response):
            bad = next((param for param in request.parameters if param.value.type not in known), None)
            if bad is None:
                return rclpy_callback(request, response)
            response.result = refusal(bad)
            return response
        return callback

    wrappers = {f'{node.get_name()}/set_parameters': one_by_one,
                f'{node.get_name()}/set_parameters_atomically': all_or_none}
    for service in node.services:
        if service.srv_name in wrappers:
            service.callback = wrappers[service.srv_name](service.callback)


def _plain(value):
    import array
    return list(value) if isinstance(value, (array.array, tuple)) else value


def _problem_text(problems) -> str:
    return '; '.join(f'{name}: {reason}' for name, reason in problems)


def _fatal(node: Node, problems) -> None:
    what = f'parameter {problems[0][0]}: {problems[0][1]}' if len(problems) == 1 else \
        f'parameters: {_problem_text(problems)}'
    node.get_logger().fatal(what)
    raise SystemExit(2)


def declare_parameters(node: Node, table, defaults: dict | None = None, names=None,
                       on_change: dict | None = None) -> ParameterValues:
    """Declare the parameters of `table` (a machine_ctrl.parameters.NodeParameters, or a
    tuple of ParameterSpec) on `node` with descriptors built from it, and return the typed
    values of every parameter of the node declared so far.

    `names`: only these (a node may declare in steps when a default depends on another
    value); parameters the node has already declared are skipped, and so are templates (a
    node declares their instances as a table of its own). `defaults`: the defaults the
    table leaves to the node (default None). Every override is checked against the table
    first: a bad one ends the node with one line on the log (exit 2); so does
    `use_sim_time:=false` for a node on the simulated clock. Later sets are refused with
    the reason (read-only ones by rclpy); a live parameter needs an
    `on_change[name](value)` hook, called after each accepted set."""
    if not isinstance(table, parameters.NodeParameters):
        table = parameters.NodeParameters(node.get_name(), tuple(table))
    state = getattr(node, '_machine_ctrl_parameters', None)
    if state is None:
        state = _Declared(node)
        node._machine_ctrl_parameters = state
        given_sim_time = node._parameter_overrides.get(USE_SIM_TIME)     # noqa: SLF001
        if given_sim_time is not None and (problem := state.sim_time_problem(given_sim_time.value)) is not None:
            _fatal(node, [(USE_SIM_TIME, problem.split(': ', 1)[1])])
    defaults, on_change = defaults or {}, on_change or {}
    wanted = [spec for spec in table if (names is None or spec.name in names) and spec.name not in state.values
              and not spec.template]
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
        _fatal(node, problems)
    for spec in wanted:
        value = node.declare_parameter(spec.name, default_of[spec.name], descriptor(spec, table)).value
        state.values[spec.name] = _plain(value)
        state.tables[spec.name] = table
        if spec.live:
            state.on_change[spec.name] = on_change[spec.name]
    return state.values


def machine_parameter(node: Node, belief: bool = False) -> MachineConfig:
    """The `machine` parameter (name or YAML path), loaded, with the files of the `belief`
    parameter merged over it where the node has one (a node holding laws); a bad config or
    belief file, or a control period the graph's step clock cannot stamp (not a whole number
    of ns), ends the node with one line on the log."""
    specs = (parameters.MACHINE, parameters.BELIEF) if belief else (parameters.MACHINE,)
    values = declare_parameters(node, specs)
    try:
        machine = load_machine(values.machine, belief=[f for f in values.belief if f] if belief else ())
        contract.StepClock.of(machine)
        return machine
    except ConfigError as exc:
        node.get_logger().fatal(str(exc))
    except ValueError as exc:
        node.get_logger().fatal(f'{machine.yaml_path}: control_period: {exc} (a graph stamps every step in integer ns)')
    raise SystemExit(2)


# --- the servo's live law gains ---------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class GainParameter:
    """One live gain of an axis's law as a ROS parameter (an instance of the servo table's
    template ``gains.<axis>.<gain>``)."""
    spec: parameters.ParameterSpec       # name gains.<axis>.<gain>, live, range as the config checks it
    axis: str
    gain: str                            # the field of the law's gains dataclass
    default: float                       # the machine config's value

    @property
    def name(self) -> str:
        return self.spec.name


def gain_parameters(machine: MachineConfig, axes) -> list[GainParameter]:
    """The live gains of the laws of `axes` (the law each axis's config names), in axis
    order and the law's parameter order, from the law classes' declarations alone."""
    from machine_ctrl.control.law import live_parameters, value_check
    from machine_ctrl.control.registry import law_entry
    template = parameters.SERVO.spec('gains.<axis>.<gain>')
    result = []
    for axis in axes:
        control = machine.axis(axis).control
        if control is None:
            continue
        entry = law_entry(control.law)
        gains = getattr(control, control.law)
        for p in live_parameters(entry.law):
            check = value_check(entry.gains, p.name)
            name = f'gains.{axis}.{p.name}'
            spec = parameters.ParameterSpec(
                name, parameters.DOUBLE, float(getattr(gains, p.name)), p.unit,
                f'{axis} {control.law}: {p.description}; live from the next step: {p.live}',
                low=0.0 if check else None, low_open=check == 'positive', live=True,
                constraint=('> 0' if check == 'positive' else '>= 0' if check == 'nonnegative' else 'finite')
                + f'; with the other gains of {axis}: the conditions of {control.law} (README "Node parameters")')
            assert template.matches(name), name
            result.append(GainParameter(spec, axis, p.name, spec.default))
    return result


# --- the shipped parameter files --------------------------------------------------------------

PARAMS_DIR = Path(__file__).resolve().parents[2] / 'config' / 'params'
SHIPPED_MACHINES = ('micromill_9axis', 'trt_5axis')


def _section(table: parameters.NodeParameters, values: dict) -> dict:
    """A node's ros__parameters: the table's defaults in table order, then `values` over them."""
    out = {}
    for spec in table.parameters:
        if spec.template:
            continue
        if spec.name in values:
            out[spec.name] = values[spec.name]
        elif spec.default is not None and not (spec.required and not spec.default):
            out[spec.name] = spec.default
    for name, value in values.items():
        if name not in out:
            out[name] = value
    if table.sim_time:
        out[USE_SIM_TIME] = True
    return out


def _nested(flat: dict) -> dict:
    """a.b.c keys as nested maps (how ros2 param dump writes them; rcl joins them back)."""
    out: dict = {}
    for key, value in flat.items():
        *path, last = key.split('.')
        node = out
        for part in path:
            node = node.setdefault(part, {})
        node[last] = value
    return out


def params_document(machine: MachineConfig) -> dict:
    """The ROS parameter file of `machine`'s bringup graph (machine_ctrl.ros.graph
    default_graph with the trajectory node and contour_error, plus compensation when the
    machine has a fine stage to compensate with, and the recorder), every node keyed
    ``/**/<name>`` (any namespace): each node's table defaults, the graph's values, the
    machine by name, the servos' live gains from the machine config, use_sim_time for the
    nodes on the simulated clock. Required values without a default (compensation `model`,
    recorder `output` and `session`) are left to the command line."""
    from machine_ctrl.ros.graph import default_graph
    nodes = []
    for spec in default_graph(machine, contour=None, contour_error=True):
        values = {**spec.parameters, 'machine': machine.name}
        if spec.table is parameters.SERVO:
            values.update({g.name: g.default for g in gain_parameters(machine, values['axes'])})
        nodes.append((spec.name, spec.table, values))
    if machine.fine_axes:
        nodes.append(('compensation', parameters.COMPENSATION, {'machine': machine.name}))
    nodes.append(('recorder', parameters.RECORDER, {'machine': machine.name}))
    document = {f'/**/{name}': {'ros__parameters': _nested(_section(table, values))} for name, table, values in nodes}
    # the session facts describe one graph (bringup and the launch file compute them): a params
    # file given after them (launch params_file:=) must not blank them
    del document['/**/recorder']['ros__parameters']['session']
    return document


def params_file_text(machine: MachineConfig) -> str:
    between = contract.TRAJECTORY_REFERENCE.name
    header = (
        f'# ROS 2 parameters of the {machine.name} bringup graph, one section per node, keyed /**/<node>\n'
        '# so that they apply in any namespace:\n'
        f'#   <executable> --ros-args -r __node:=<node> --params-file config/params/{machine.name}.yaml\n'
        '# Generated by `python -m machine_ctrl.ros.node_parameters --write config/params` from\n'
        '# machine_ctrl/parameters.py, the bringup graph and the machine config (test/test_ros_parameters.py\n'
        '# checks that this file is what the code generates): edit those, not this file.\n'
        '# Left to the command line: compensation `model` (-p model:=MODEL.yaml; the trajectory node then\n'
        f'# publishes on {between}: -p output_topic:={between}), recorder `output` and `session`.\n')
    from machine_ctrl.ros.graph import params_yaml
    return header + params_yaml(params_document(machine))


def write_params_files(directory=PARAMS_DIR, machines=SHIPPED_MACHINES) -> list[Path]:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in machines:
        path = directory / f'{name}.yaml'
        path.write_text(params_file_text(load_machine(name)))
        paths.append(path)
    return paths


def main(argv=None) -> int:
    """python -m machine_ctrl.ros.node_parameters --write DIR | --check DIR"""
    import argparse
    parser = argparse.ArgumentParser(prog='python -m machine_ctrl.ros.node_parameters',
                                     description='the shipped ROS parameter files of the bringup graphs')
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument('--write', metavar='DIR', help='write <machine>.yaml for every shipped machine')
    group.add_argument('--check', metavar='DIR', help='exit 1 when a file differs from what the code generates')
    args = parser.parse_args(argv)
    if args.write:
        for path in write_params_files(args.write):
            print(path)
        return 0
    stale = [name for name in SHIPPED_MACHINES
             if not (Path(args.check) / f'{name}.yaml').is_file()
             or (Path(args.check) / f'{name}.yaml').read_text() != params_file_text(load_machine(name))]
    for name in stale:
        print(f'{args.check}/{name}.yaml: differs from what the code generates (--write to update)', file=sys.stderr)
    return 1 if stale else 0


if __name__ == '__main__':
    raise SystemExit(main())
