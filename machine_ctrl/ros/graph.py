"""The node graph of a machine (design.md "The node graph") as data, startable with every
node in its own process or all in one process (one executor). Used by the graph tests and
benchmarks; `machine-ctrl bringup` ([7/7]) builds on it.

Default layout for a machine with dual-stage pairs: hw_sim, one servo node per stage
(fine stage: every axis with the drive type of the coupling's fine axes — the whole maglev
table; coarse stage: the other controlled axes), dual_stage, and the reference source:
the trajectory node (contour None; the machine starts at home, or where `hw_sim` says),
or the reference node playing a test contour (the machine starts where it starts). With a
geometric error model, the compensation node sits between the trajectory node (publishing
on /trajectory/reference) and the servos (reading /reference).
"""
from __future__ import annotations

import atexit
import shutil
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import rclpy
import yaml
from rclpy.parameter import Parameter

from machine_ctrl import contract, parameters
from machine_ctrl.model.config import MachineConfig
from trajectory.contours import contour_reference


@dataclass(frozen=True)
class NodeSpec:
    """One node of a graph, as data: its name and namespace, where its class is, and its
    parameter values — typed by the node's table (machine_ctrl.parameters), checked when
    the spec is made (ValueError naming the node and the parameter). Every node remaps
    ROS's /clock into its namespace (contract.CLOCK_REMAP)."""
    name: str
    module: str                       # python -m <module>
    cls: str                          # class in that module
    parameters: dict = field(default_factory=dict)
    namespace: str = ''               # '' (the root) or '/mill1'

    def __post_init__(self):
        object.__setattr__(self, 'namespace', contract.normal_namespace(self.namespace))
        table = self.table
        values = {}
        for key, value in self.parameters.items():
            try:
                values[key] = parameters.coerce(table.spec(key), value)
            except KeyError:
                raise ValueError(f'{self.name}: {table.executable} has no parameter {key!r}') from None
        problems = parameters.check_values(table, {**table.defaults(), **values})
        if problems:
            raise ValueError(f'{self.name}: ' + '; '.join(f'parameter {n}: {r}' for n, r in problems))
        object.__setattr__(self, 'parameters', values)

    @property
    def table(self) -> parameters.NodeParameters:
        return parameters.table(self.module.rsplit('.', 1)[-1])

    @property
    def full_name(self) -> str:
        return f'{self.namespace}/{self.name}'

    def params_document(self) -> dict:
        """This node's section of a ROS parameters file."""
        return {self.full_name: {'ros__parameters': dict(self.parameters)}}

    def ros_args(self) -> list[str]:
        """The remapping arguments after --ros-args: name, namespace, clock."""
        args = ['-r', f'__node:={self.name}', '-r', '{}:={}'.format(*contract.CLOCK_REMAP)]
        return args + (['-r', f'__ns:={self.namespace}'] if self.namespace else [])

    def argv(self, params_dir=None) -> list[str]:
        """Command line of this node as its own process: the parameters go in a ROS
        parameters file (`params_dir`/<name>.params.yaml, or a temporary file kept until
        this process exits)."""
        args = [sys.executable, '-m', self.module, '--ros-args', *self.ros_args()]
        if self.parameters:
            args += ['--params-file', str(write_params_file([self], params_dir, self.name))]
        return args

    def create(self):
        """The node, in this process (rclpy must be initialized), with its parameters as
        overrides."""
        module = __import__(self.module, fromlist=[self.cls])
        overrides = [Parameter(k, value=v) for k, v in self.parameters.items()]
        return getattr(module, self.cls)(name=self.name, namespace=self.namespace or None,
                                         cli_args=['--ros-args', *self.ros_args()], parameter_overrides=overrides)

    def to_data(self) -> dict:
        return {'name': self.name, 'namespace': self.namespace, 'module': self.module, 'class': self.cls,
                'parameters': dict(self.parameters)}

    @classmethod
    def from_data(cls, data: dict) -> NodeSpec:
        return cls(data['name'], data['module'], data['class'], dict(data.get('parameters') or {}),
                   data.get('namespace') or '')


class _Dumper(yaml.SafeDumper):
    """ROS parameter files: strings always quoted (rcl takes an unquoted true, y or 1e3 as a
    bool or a number; a quoted scalar is always a string), lists in flow style, no aliases."""

    def ignore_aliases(self, data) -> bool:
        return True


def _mapping(dumper, data):
    """Keys plain (node and parameter names), values as their representers make them."""
    pairs = [(yaml.ScalarNode('tag:yaml.org,2002:str', str(key)), dumper.represent_data(value))
             for key, value in data.items()]
    return yaml.MappingNode('tag:yaml.org,2002:map', pairs, flow_style=False)


_Dumper.add_representer(str, lambda dumper, value: dumper.represent_scalar('tag:yaml.org,2002:str', value, style="'"))
_Dumper.add_representer(list, lambda dumper, value: dumper.represent_sequence('tag:yaml.org,2002:seq', value,
                                                                              flow_style=True))
_Dumper.add_representer(dict, _mapping)


_temporary: list[Path] = []


def params_yaml(document) -> str:
    """YAML text of a ROS parameters document (also of node specs: the same typing rules)."""
    return yaml.dump(document, Dumper=_Dumper, sort_keys=False, width=120)


def _output_dir(directory) -> Path:
    if directory is not None:
        Path(directory).mkdir(parents=True, exist_ok=True)
        return Path(directory)
    if not _temporary:
        _temporary.append(Path(tempfile.mkdtemp(prefix='machine_ctrl_params_')))
        atexit.register(shutil.rmtree, _temporary[0], True)
    return _temporary[0]


def write_params_file(specs, directory=None, stem: str = 'graph') -> Path:
    """A ROS parameters file (`<directory>/<stem>.params.yaml`; a fresh temporary one
    without a directory) with a section per node spec; the values as typed by the tables
    (an empty array cannot be written: ROS cannot type it)."""
    document = {}
    for spec in specs:
        for key, value in spec.parameters.items():
            if isinstance(value, list) and not value:
                raise ValueError(f'{spec.name}: parameter {key}: an empty list cannot go into a parameters file')
        document.update(spec.params_document())
    if directory is None:
        handle = tempfile.NamedTemporaryFile('w', suffix='.params.yaml', prefix=f'{stem}-', delete=False,
                                             dir=_output_dir(None))
        with handle:
            handle.write(params_yaml(document))
        return Path(handle.name)
    path = _output_dir(directory) / f'{stem}.params.yaml'
    path.write_text(params_yaml(document))
    return path


def write_specs(specs, path) -> Path:
    """The node specs of a graph as a YAML file (`python -m machine_ctrl.ros.graph --specs`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(params_yaml({'nodes': [spec.to_data() for spec in specs]}))
    return path


def single_process_argv(specs: list[NodeSpec], directory) -> list[str]:
    """Every node of `specs` in one process: the specs go to `directory`/graph.yaml as data
    (names, classes, typed parameter values), and that process creates the nodes with
    them as parameter overrides."""
    path = write_specs(specs, Path(directory) / 'graph.yaml')
    return [sys.executable, '-m', 'machine_ctrl.ros.graph', '--specs', str(path)]


def read_specs(path) -> list[NodeSpec]:
    data = yaml.safe_load(Path(path).read_text()) or {}
    return [NodeSpec.from_data(item) for item in data.get('nodes') or []]


def default_graph(machine: MachineConfig, contour: str | None = 'circle', dual_stage: bool = True,
                  hw_sim: dict | None = None, compensation_model: str | None = None,
                  contour_error: bool = False, namespace: str = '', belief: Sequence[str] = ()) -> list[NodeSpec]:
    """The nodes of `machine`'s graph; `belief`: files of the controllers' values, given to the
    servo nodes (their `belief` parameter)."""
    fine_types = {machine.axis(name).drive.type for name in machine.fine_axes}
    controlled = [a for a in machine.axes if a.control is not None]
    fine = [a.name for a in controlled if a.drive.type in fine_types]
    coarse = [a.name for a in controlled if a.drive.type not in fine_types]
    common = {'machine': str(machine.yaml_path)}
    sources = []
    if compensation_model is not None:
        sources.append(NodeSpec('compensation', 'machine_ctrl.ros.compensation_node', 'CompensationNode',
                                {**common, 'model': str(compensation_model)}))
    if contour is None:
        output = contract.trajectory_output(compensation_model is not None).name
        sources.append(NodeSpec('trajectory', 'machine_ctrl.ros.trajectory_node', 'TrajectoryNode', {**common, 'output_topic': output}))
        hw = {**common, **(hw_sim or {})}
    else:   # a contour has no approach move: the machine starts where the contour starts
        if compensation_model is not None:
            raise ValueError('compensation needs the trajectory node (contour None)')
        sources.append(NodeSpec('reference', 'machine_ctrl.ros.reference_node', 'ReferenceNode',
                                {**common, 'contour': contour}))
        start = [float(v) for v in contour_reference(machine, contour).position[0]]
        hw = {**common, 'initial_position': start, **(hw_sim or {})}
    servo = {**common, 'belief': [str(Path(f).resolve()) for f in belief]} if belief else common
    specs = [NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode', hw),
             NodeSpec('servo_coarse', 'machine_ctrl.ros.servo_node', 'ServoNode', {**servo, 'axes': coarse})]
    if fine:
        specs.append(NodeSpec('servo_fine', 'machine_ctrl.ros.servo_node', 'ServoNode', {**servo, 'axes': fine}))
        specs.append(NodeSpec('dual_stage', 'machine_ctrl.ros.dual_stage_node', 'DualStageNode',
                              {**common, 'dual_stage': dual_stage}))
    if contour_error:
        sources.append(NodeSpec('contour_error', 'machine_ctrl.ros.contour_error_node', 'ContourErrorNode', common))
    specs = specs + sources
    return [NodeSpec(s.name, s.module, s.cls, s.parameters, namespace) for s in specs] if namespace else specs


def create_nodes(specs: list[NodeSpec]) -> list:
    if not rclpy.ok():
        raise RuntimeError('rclpy is not initialized')
    return [spec.create() for spec in specs]


def main(argv=None) -> int:
    """All nodes of a graph in this one process: python -m machine_ctrl.ros.graph — the
    default graph of a machine from the options, or the node specs of a file (--specs,
    written by write_specs: how `machine-ctrl bringup --single-process` starts it)."""
    import argparse

    from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
    from machine_ctrl.ros.node_common import init, spin

    parser = argparse.ArgumentParser(prog='python -m machine_ctrl.ros.graph', description=main.__doc__)
    parser.add_argument('--specs', metavar='FILE', help='node specs (YAML); no other option then')
    group = parser.add_argument_group('the default graph (not with --specs)')
    graph_options = [
        group.add_argument('--machine', help=f'default {DEFAULT_MACHINE}'),
        group.add_argument('--contour', help="test contour of the reference node (default circle), or 'none' "
                           'for the trajectory node'),
        group.add_argument('--no-dual-stage', action='store_true', help='start with the dual-stage coupling off'),
        group.add_argument('--namespace', default='', help="ROS namespace (default: the root)"),
        group.add_argument('--hw-sim', action='append', default=[], metavar='KEY=VALUE',
                           help='hw_sim parameter (value as YAML), e.g. min_subscribers=4')]
    args = parser.parse_args(argv)
    if args.specs is not None:
        given = [option.option_strings[0] for option in graph_options if getattr(args, option.dest) != option.default]
        if given:
            parser.error(f'--specs takes no other option, got {", ".join(given)}')
        specs = read_specs(args.specs)
    else:
        hw = {k: yaml.safe_load(v) for k, v in (item.split('=', 1) for item in args.hw_sim)}
        contour = 'circle' if args.contour is None else args.contour
        specs = default_graph(load_machine(args.machine or DEFAULT_MACHINE), None if contour == 'none' else contour,
                              not args.no_dual_stage, hw, namespace=args.namespace)
    init()
    try:
        nodes = create_nodes(specs)
    except SystemExit as exc:              # a node refused its parameters (one line logged)
        rclpy.try_shutdown()
        return int(exc.code or 1)
    spin(nodes)             # ends the process


if __name__ == '__main__':
    raise SystemExit(main())
