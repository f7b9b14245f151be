"""Offline runner: steps exactly the plant, servo and coupling objects the nodes use, in a
plain loop without ROS — for experiments, tests and benchmarks. Per step k:

    measurement k  ->  dual-stage offsets  ->  contour corrections  ->  servo commands
                   ->  plant step k -> k+1

which is the lock-step graph's order (design.md "Time"), so both give the same numbers.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hw_sim import compiled_loop
from hw_sim.simulator import MachineSimulator
from machine_ctrl.model.config import DEFAULT_MACHINE, MachineConfig, load_machine
from machine_ctrl.control.contour_coupling import ContourCoupling
from machine_ctrl.control.dual_stage import DualStageCoupling, apply_offsets
from machine_ctrl.model.reference import Reference
from machine_ctrl.control.servo import ServoGroup

PROGRESS_STEPS = 10000       # progress(k, steps) after every this many steps


@dataclass
class RunRecord:
    """Per step k (rows): reference, measured (position, velocity) and true positions at
    step k, the efforts applied over the period before it (what /joint_states carries), the
    commands computed at k, the dual-stage coupling's offsets (of `offset_axes`) and, on a
    machine with a tracker, its readings (x, y, z) of step k."""
    axis_names: tuple[str, ...]
    period: float
    reference: np.ndarray
    measured: np.ndarray
    measured_velocity: np.ndarray
    effort: np.ndarray
    true: np.ndarray
    commands: np.ndarray
    offsets: np.ndarray
    fault: str | None = None
    saturations: int = 0
    offset_axes: tuple[str, ...] = field(default_factory=tuple)     # MachineConfig.offset_axes
    tracker: np.ndarray | None = None     # (steps, 3), m; None without a tracker
    contour_invalid: dict[str, int] | None = None    # with contour control: steps per channel without a valid estimate
    compiled: bool = False       # stepped by the compiled loop (hw_sim/compiled_loop.py), else the Python loop

    def column(self, array: np.ndarray, axis: str) -> np.ndarray:
        return array[:, self.axis_names.index(axis)]


def run(machine: MachineConfig, reference: Reference, dual_stage: bool = True,
        laws: dict[str, str] | None = None, feedforward: bool = True, steps: int | None = None,
        progress=None, initial_position=None, forces: dict[str, np.ndarray] | None = None,
        contour_control: bool = False, compiled: bool = True) -> RunRecord:
    """Run `reference` for `steps` steps (default its length; past its end the last
    position is held) from `initial_position` (default where the reference starts; hw_sim
    starts at its `initial_position` parameter, the machine's home by default). `forces`:
    per axis an external force (N) per step on its moving mass (MachineSimulator.set_force;
    the last value holds past the array's end). `contour_control`: the machine's cross-coupled
    contour control on from the start (machine_ctrl/control/contour_coupling.py; past the
    reference's end its correction fades out). `compiled`: step in hw_sim/compiled_loop.py where
    it covers the machine and the options (the same numbers, bit for bit), else (or False)
    in the Python loop below."""
    steps = len(reference) if steps is None else steps
    start = reference.position[0] if initial_position is None else initial_position
    simulator = MachineSimulator(machine, initial_position=start)
    servo = ServoGroup(machine, machine.axis_names, laws, feedforward)
    coupling = DualStageCoupling(machine, dual_stage=dual_stage)
    offset_index = [machine.axis_names.index(a) for a in coupling.offset_axes]
    contour = None
    if contour_control:
        contour = ContourCoupling(machine, enabled=True)
        contour.add_reference(0, reference.position, reference.velocity, reference.acceleration)
        contour_index = [machine.axis_names.index(a) for a in contour.axes]
    n = len(machine.axes)
    forces = {axis: np.asarray(f, dtype=float).reshape(-1) for axis, f in (forces or {}).items()}
    empty = [axis for axis, f in forces.items() if not len(f)]
    if empty:
        raise ValueError(f'forces for {", ".join(empty)}: no values')
    packed = None if contour is not None or forces or not compiled else compiled_loop.pack(simulator, servo, coupling)
    if packed is not None:
        rec, fault = _run_compiled(packed, simulator, reference, steps, progress)
        return RunRecord(machine.axis_names, machine.control_period, fault=fault,
                         saturations=packed.saturation_count, offset_axes=coupling.offset_axes, compiled=True,
                         **rec)
    names = ('reference', 'measured', 'measured_velocity', 'effort', 'true', 'commands')
    rows = [[] for _ in names]            # per step one tuple each; arrays at the end (cheaper per step)
    reference_rows, measured_rows, velocity_rows, effort_rows, true_rows, command_rows = rows
    offsets_rows, tracker_rows = [], []
    for k, (ref_pos, ref_vel, ref_acc) in enumerate(reference.rows(steps)):
        for axis, f in forces.items():
            simulator.set_force(axis, f[min(k, len(f) - 1)])
        measured = simulator.measurement
        offsets = coupling.step(ref_pos, measured.position, measured.tracker).offsets
        servo_ref = apply_offsets(ref_pos, offset_index, offsets)
        if contour is not None:
            servo_ref = apply_offsets(servo_ref, contour_index, contour.step(k, measured.position).corrections)
        commands = servo.step(servo_ref, ref_vel, ref_acc, measured.position, measured.velocity,
                              measured.acceleration)
        reference_rows.append(ref_pos)
        measured_rows.append(measured.position)
        velocity_rows.append(measured.velocity)
        effort_rows.append(measured.effort)
        true_rows.append(simulator.true_position)
        command_rows.append(commands)
        offsets_rows.append(offsets)
        if measured.tracker:
            tracker_rows.append(measured.tracker)
        simulator.step(commands)
        if progress is not None and k % PROGRESS_STEPS == 0:
            progress(k, steps)
    rec = {name: np.array(r, dtype=float).reshape(steps, n) for name, r in zip(names, rows)}
    return RunRecord(machine.axis_names, machine.control_period,
                     offsets=np.array(offsets_rows, dtype=float).reshape(steps, len(offset_index)),
                     fault=simulator.fault, saturations=coupling.saturation_count,
                     offset_axes=coupling.offset_axes,
                     tracker=np.array(tracker_rows, dtype=float).reshape(steps, 3) if machine.tracker else None,
                     contour_invalid=None if contour is None else dict(contour.invalid_steps), **rec)


def warm() -> None:
    """Load (or, the first time after a change of hw_sim/compiled_loop.py, compile) the
    compiled loop now rather than in the first run: two steps of the default machine at home."""
    machine = load_machine(DEFAULT_MACHINE)
    run(machine, Reference.hold(machine.axis_names, machine.control_period, machine.home, 2))


def _run_compiled(packed, simulator: MachineSimulator, reference: Reference, steps: int, progress):
    """The rows of `steps` steps by the compiled loop, and the fault the simulator would
    name (its own messages, from the compiled loop's fault kind, step and axis)."""
    ref_p, ref_v, ref_a = reference.arrays(steps)
    n = ref_p.shape[1]
    rec = {name: np.zeros((steps, n)) for name in ('measured', 'measured_velocity', 'effort', 'true', 'commands')}
    rec['offsets'] = np.zeros((steps, packed.fine_count))
    # progress after steps 0, PROGRESS_STEPS, 2 PROGRESS_STEPS, ... as the Python loop calls it
    bounds = [0, steps] if progress is None else [0, *range(1, steps, PROGRESS_STEPS), steps]
    for first, stop in zip(bounds, bounds[1:]):
        packed.run(ref_p, ref_v, ref_a, first, stop, rec)
        if progress is not None and (stop - 1) % PROGRESS_STEPS == 0:
            progress(stop - 1, steps)
    kind, step, index = packed.fault
    fault = None
    if kind == compiled_loop.NON_FINITE:
        fault = simulator.command_fault(tuple(rec['commands'][step].tolist()))
    elif kind == compiled_loop.STROKE:
        fault = simulator.stroke_fault(packed.true_position)
    elif kind == compiled_loop.RUN_AWAY:
        axis = simulator.machine.axes[index]
        raise ValueError(f'step {step}: the position of {axis.name} is {packed.true_position[index]} {axis.unit}, '
                         f'not finite: the simulation cannot go on')
    rec['reference'] = ref_p
    return rec, fault
