"""A G-code part program planned (issue [7/8], part 1): read (trajectory.gcode), cut into
pieces, and each piece planned by :func:`trajectory.planner.plan` with its feed, starting in
the configuration where the piece before it ended (at rest: an exact stop between pieces).
The references of the pieces, one after the other, are the program's (the first row of each
later piece, equal to the last of the one before, taken once).

A result, not an exception (as trajectory.planner): :class:`ProgramPlan` has the planner's
status and a reason that names the program's lines (``part.ngc: lines 5-9 (piece 3 of 7):
...``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.model.reference import Reference
from trajectory import gcode
from trajectory.planner import PlannedPath, PlanStatus, plan

# file names read as G-code (a path of another name is CL data or a built-in path)
SUFFIXES = ('.ngc', '.nc', '.gcode', '.tap')


def is_program(name) -> bool:
    return str(name).lower().endswith(SUFFIXES)


@dataclass(frozen=True)
class ProgramPlan:
    """`status` / `reason` as the planner's; the program's pieces and, when ok, the plan of
    each (`plans`); `notes`: what the reader ignored; `planning_time` (s, wall)."""
    status: PlanStatus
    reason: str = ''
    pieces: tuple[gcode.Piece, ...] = ()
    plans: tuple[PlannedPath, ...] = ()
    notes: tuple[str, ...] = ()
    planning_time: float = 0.0

    @property
    def ok(self) -> bool:
        return self.status == PlanStatus.OK

    def reference(self) -> Reference:
        """The pieces' references one after the other."""
        refs = [p.reference for p in self.plans]
        parts = [refs[0]] + [_from_row(r, 1) for r in refs[1:]]
        return Reference(refs[0].axis_names, refs[0].period, *(np.vstack([getattr(r, name) for r in parts])
                                                              for name in ('position', 'velocity', 'acceleration')))

    def summary(self) -> dict:
        per_piece = [{'lines': list(piece.lines), 'rapid': piece.rapid, 'feed': piece.feed, 'points': len(piece.cl),
                      'stop_after': piece.stop_after, **planned.summary()}
                     for piece, planned in zip(self.pieces, self.plans)]
        peaks = {}
        for planned in self.plans:
            for axis, ratios in planned.peak_ratios.items():
                mine = peaks.setdefault(axis, dict.fromkeys(ratios, 0.0))
                for key, value in ratios.items():
                    mine[key] = max(mine[key], value)
        return {'traversal_time': sum(p.traversal_time for p in self.plans), 'planning_time': self.planning_time,
                'samples': sum(len(p.reference) for p in self.plans) - (len(self.plans) - 1),
                'max_position_deviation': max(p.max_position_deviation for p in self.plans),
                'max_orientation_deviation': max(p.max_orientation_deviation for p in self.plans),
                'peak_ratios': peaks, 'peak_feed_ratio': max(p.sampling.feed_ratio for p in self.plans),
                'pieces': per_piece, 'notes': list(self.notes)}


def _from_row(reference: Reference, first: int) -> Reference:
    return Reference(reference.axis_names, reference.period, reference.position[first:],
                     reference.velocity[first:], reference.acceleration[first:])


def plan_program(program, machine, kinematics: Kinematics | None = None) -> ProgramPlan:
    """Plan the program (a trajectory.gcode.Program, or the path of a G-code file) on
    `machine` (MachineConfig or name): every piece or none. `kinematics`: the machine's,
    when the caller has them built (default: built here)."""
    start = time.perf_counter()

    def failed(status: PlanStatus, reason: str, **done) -> ProgramPlan:
        return ProgramPlan(status, reason, planning_time=time.perf_counter() - start, **done)

    if not isinstance(program, gcode.Program):
        read = gcode.read(program)
        if not read.ok:
            return failed(PlanStatus.INVALID_INPUT, read.reason)
        program = read.program
    if not program.motions:
        return failed(PlanStatus.INVALID_INPUT, f'{program.source}: no motion in the program')
    try:
        if not isinstance(machine, MachineConfig):
            machine = load_machine(machine)
        kinematics = Kinematics.from_config(machine) if kinematics is None else kinematics
        pieces = gcode.pieces(program, gcode.tool_axis_of(kinematics, machine))
    except gcode.GcodeError as exc:
        return failed(PlanStatus.INVALID_INPUT, f'{program.source}:{exc.line}: {exc}')
    except (ValueError, OSError) as exc:
        return failed(PlanStatus.INVALID_INPUT, str(exc))
    plans, q0 = [], None
    for n, piece in enumerate(pieces, start=1):
        result = plan(piece.cl, machine, feed=piece.feed, q0=q0, kinematics=kinematics)
        if not result.ok:
            return failed(result.status, f'{program.source}: {piece.where} (piece {n} of {len(pieces)}'
                                         f'{", a rapid" if piece.rapid else ""}): {result.reason}',
                          pieces=tuple(pieces), notes=program.notes)
        plans.append(result.plan)
        q0 = result.plan.reference.position[-1]
    return ProgramPlan(PlanStatus.OK, '', tuple(pieces), tuple(plans), program.notes, time.perf_counter() - start)
