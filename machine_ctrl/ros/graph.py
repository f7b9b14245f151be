"""The node graph of a machine (design.md "The node graph") as data, startable with every
node in its own process or all in one process (one executor). Used by the graph tests and
benchmarks; `machine-ctrl bringup` ([7/7]) builds on it.

Default layout for a machine with dual-stage pairs: hw_sim, one servo node per stage
(fine stage: every axis with the drive type of the pairs' fine axes — the whole maglev
table; coarse stage: the other controlled axes), dual_stage, and the reference source:
the trajectory node (contour None; the machine starts at home, or where `hw_sim` says),
or the reference node playing a test contour (the machine starts where it starts). With a
geometric error model, the compensation node sits between the trajectory node (publishing
on /trajectory/reference) and the servos (reading /reference).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field

import rclpy
from rclpy.parameter import Parameter

from machine_ctrl.model.config import MachineConfig
from trajectory.contours import contour_reference


@dataclass(frozen=True)
class NodeSpec:
    name: str
    module: str                       # python -m <module>
    cls: str                          # class in that module
    parameters: dict = field(default_factory=dict)

    def argv(self) -> list[str]:
        """Command line of this node as its own process."""
        args = [sys.executable, '-m', self.module, '--ros-args', '-r', f'__node:={self.name}']
        for key, value in self.parameters.items():
            args += ['-p', f'{key}:={_param_text(value)}']
        return args

    def create(self):
        """The node, in this process (rclpy must be initialized)."""
        module = __import__(self.module, fromlist=[self.cls])
        overrides = [Parameter(k, value=v) for k, v in self.parameters.items()]
        return getattr(module, self.cls)(name=self.name, parameter_overrides=overrides)


def _param_text(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        if any(isinstance(v, float) for v in value):     # ROS parameter arrays have one type
            value = [float(v) for v in value]
        return '[' + ','.join(_param_text(v) for v in value) + ']'
    return str(value)


def default_graph(machine: MachineConfig, contour: str | None = 'circle', dual_stage: bool = True,
                  hw_sim: dict | None = None, compensation_model: str | None = None,
                  contour_error: bool = False) -> list[NodeSpec]:
    fine_types = {machine.axis(p.fine).drive.type for p in machine.dual_stage}
    controlled = [a for a in machine.axes if a.control is not None]
    fine = [a.name for a in controlled if a.drive.type in fine_types]
    coarse = [a.name for a in controlled if a.drive.type not in fine_types]
    common = {'machine': str(machine.yaml_path)}
    sources = []
    if compensation_model is not None:
        sources.append(NodeSpec('compensation', 'machine_ctrl.ros.compensation_node', 'CompensationNode',
                                {**common, 'model': str(compensation_model)}))
    if contour is None:
        output = '/trajectory/reference' if compensation_model is not None else '/reference'
        sources.append(NodeSpec('trajectory', 'machine_ctrl.ros.trajectory_node', 'TrajectoryNode', {**common, 'output_topic': output}))
        hw = {**common, **(hw_sim or {})}
    else:   # a contour has no approach move: the machine starts where the contour starts
        if compensation_model is not None:
            raise ValueError('compensation needs the trajectory node (contour None)')
        sources.append(NodeSpec('reference', 'machine_ctrl.ros.reference_node', 'ReferenceNode',
                                {**common, 'contour': contour}))
        start = [float(v) for v in contour_reference(machine, contour).position[0]]
        hw = {**common, 'initial_position': start, **(hw_sim or {})}
    specs = [NodeSpec('hw_sim', 'machine_ctrl.ros.hw_sim_node', 'HwSimNode', hw),
             NodeSpec('servo_coarse', 'machine_ctrl.ros.servo_node', 'ServoNode', {**common, 'axes': coarse})]
    if fine:
        specs.append(NodeSpec('servo_fine', 'machine_ctrl.ros.servo_node', 'ServoNode', {**common, 'axes': fine}))
        specs.append(NodeSpec('dual_stage', 'machine_ctrl.ros.dual_stage_node', 'DualStageNode',
                              {**common, 'enabled': dual_stage}))
    if contour_error:
        sources.append(NodeSpec('contour_error', 'machine_ctrl.ros.contour_error_node', 'ContourErrorNode', common))
    return specs + sources


def create_nodes(specs: list[NodeSpec]) -> list:
    if not rclpy.ok():
        raise RuntimeError('rclpy is not initialized')
    return [spec.create() for spec in specs]


def main(argv=None) -> int:
    """All nodes of the default graph in this one process: python -m machine_ctrl.ros.graph."""
    import argparse

    from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
    from machine_ctrl.ros.node_common import spin

    parser = argparse.ArgumentParser(prog='python -m machine_ctrl.ros.graph', description=main.__doc__)
    parser.add_argument('--machine', default=DEFAULT_MACHINE)
    parser.add_argument('--contour', default='circle',
                        help="test contour of the reference node, or 'none' for the trajectory node")
    parser.add_argument('--no-dual-stage', action='store_true')
    parser.add_argument('--hw-sim', action='append', default=[], metavar='KEY=VALUE',
                        help='hw_sim parameter (value as YAML), e.g. min_subscribers=4')
    parser.add_argument('--compensation', metavar='MODEL', help='geometric error model: add the compensation node')
    parser.add_argument('--contour-error', action='store_true', help='add the contour error node')
    args = parser.parse_args(argv)
    import yaml
    hw = {k: yaml.safe_load(v) for k, v in (item.split('=', 1) for item in args.hw_sim)}
    contour = None if args.contour == 'none' else args.contour
    specs = default_graph(load_machine(args.machine), contour, not args.no_dual_stage, hw, args.compensation,
                          args.contour_error)
    rclpy.init()
    spin(create_nodes(specs))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
