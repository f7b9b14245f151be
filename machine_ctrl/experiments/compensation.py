"""Geometric error compensation experiments on the simulated machine (Yuen thesis, seed
000_d9dd5f6a818770e4.txt, §6.4, Tables 6.3 and 6.4, Figs. 6.15-6.19).

1. Measure: the simulated laser campaign on the true map (measurement.py) -> CSV.
2. Identify: quintic fits (fitting.py) -> the model the controller uses.
3. Table 6.3: each micromill axis alone over its measured range in 1 mm steps, the machine
   at rest (tracking error ~0, as for the thesis's laser readings): tool-tip displacement
   errors P_a,true(q) - P_i(q) without, and P_a,true(q*) - P_i(q) with compensation (q* from
   the fitted model). And the same through the servo ([8/8] part 4; the thesis read its laser
   under closed-loop control): :func:`servo_single_axis` steps the axis in the offline runner
   with every sensor and noise, and the laser reads the true tool tip at rest after each step.
4. Table 6.4: the spiral (thesis Fig. 6.1) run in the offline runner without compensation,
   compensated with the fitted model, and compensated with the true map. Tool-tip error at
   every ground-truth sample (every 10 steps, like hw_sim's /hw_sim/ground_truth/tool_pose):
   e = P_a,true(q_true) - P_i(q_ref), split into tracking e_t = P_a,true(q_true) -
   P_a,true(q_cmd) and geometric e_g = P_a,true(q_cmd) - P_i(q_ref) (q_cmd: the reference
   the servos were given).
Errors are tool tip minus ideal, i.e. -dP of Eq. (5.14); tables give |.| statistics in um.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from compensation.compensate import Compensator
from compensation.error_map import ErrorMap
from compensation.error_model import ErrorKinematics
from compensation.measurement import NOISE_DISPLACEMENT, STEP
from machine_ctrl import parameters
from machine_ctrl.model.config import MachineConfig
from hw_sim.offline import RunRecord, run
from machine_ctrl.model.reference import Reference

# Thesis Table 6.3 (um): (mean uncompensated, mean compensated, max uncompensated, max compensated)
THESIS_6_3 = {
    ('x', 'x_c'): (0.549, 0.168, 1.07, 0.443), ('y', 'x_c'): (0.2, 0.0571, 0.629, 0.265),
    ('z', 'x_c'): (0.396, 0.162, 1.1, 0.37), ('x', 'y_c'): (1.16, 0.222, 3.06, 0.626),
    ('y', 'y_c'): (1.65, 0.44, 4.18, 0.883), ('z', 'y_c'): (0.19, 0.0791, 0.693, 0.358),
    ('x', 'z_c'): (3.91, 0.844, 7.48, 2.4), ('y', 'z_c'): (0.251, 0.197, 0.9, 0.636),
    ('z', 'z_c'): (0.337, 0.115, 0.976, 0.498),
}
# Thesis Table 6.4 (um): |dP_x|, |dP_y|, |dP_z| (mean unc., mean comp., max unc., max comp.)
THESIS_6_4 = {'x': (0.97, 0.19, 6.5, 3.7), 'y': (0.79, 0.31, 6.5, 7.1), 'z': (5.2, 3.8, 65.4, 81.8)}
GROUND_TRUTH_DECIMATION = parameters.HW_SIM.spec('ground_truth_decimation').default   # hw_sim's default
# Table 6.3 through the servo. assumed (the seed states no timing): each 1 mm step a time-optimal
# jerk-limited move (moves.move_to, as a jog), then the axis held for 0.1 s to settle (~19 time
# constants of the coarse loops' ~30 Hz) and 0.05 s in which the laser averages the true tool tip
# (sampled every GROUND_TRUTH_DECIMATION-th step, as hw_sim's ground-truth topic; the interferometer's
# reading, with its noise NOISE_DISPLACEMENT, one reading per position)
STEP_SETTLE = 0.1           # s
STEP_READ = 0.05            # s
UM = 1e6


def _stats(errors: np.ndarray) -> dict:
    """mean and max |e| per direction, um."""
    a = np.abs(errors) * UM
    return {d: {'mean': float(a[:, i].mean()), 'max': float(a[:, i].max())} for i, d in enumerate('xyz')}


@dataclass
class SingleAxis:
    axis: str
    positions: np.ndarray
    uncompensated: np.ndarray       # (N, 3) m
    compensated: np.ndarray
    fine_commands: np.ndarray       # (N, 6) q*_f - q_f


def measured_positions(error_map: ErrorMap, axis: str) -> np.ndarray:
    """The 1 mm positions over `axis`'s measured range (the campaign's, thesis section 5.3)."""
    lo, hi = error_map.axes[axis].range
    return lo + STEP * np.arange(int(round((hi - lo) / STEP)) + 1)


def single_axis(machine: MachineConfig, truth: ErrorKinematics, compensator: Compensator,
                error_map: ErrorMap) -> list[SingleAxis]:
    """Table 6.3 / Figs. 6.15-6.18: each mapped axis alone, at rest, at 1 mm steps."""
    out = []
    for axis in error_map.axes:
        positions = measured_positions(error_map, axis)
        q = np.tile(np.asarray(machine.home, float), (len(positions), 1))
        q[:, machine.axis_names.index(axis)] = positions
        ideal = compensator.ideal.positions(q)
        comp = compensator.solve(q)
        out.append(SingleAxis(axis, positions, truth.positions(q) - ideal,
                              truth.positions(comp.position) - ideal,
                              (comp.position - q)[:, compensator.fine_index]))
    return out


def stepped_reference(machine: MachineConfig, axis: str, positions) -> tuple[Reference, list[slice]]:
    """`axis` at each of `positions` in turn (the others at home): held STEP_SETTLE + STEP_READ
    at each, moved between them by moves.move_to; and the steps of each reading (the last
    STEP_READ of each hold)."""
    from trajectory import moves
    index, period = machine.axis_names.index(axis), machine.control_period
    hold, read = int(round((STEP_SETTLE + STEP_READ) / period)), int(round(STEP_READ / period))
    parts, reads, length = [], [], 0
    for k, x in enumerate(positions):
        q = np.asarray(machine.home, float)
        q[index] = x
        if k:
            parts.append(moves.move_to(machine, q, moves.AxisState.at_rest(parts[-1].position[-1])))
            length += len(parts[-1]) - 1
        zeros = np.zeros((hold + 1, len(q)))
        parts.append(Reference(machine.axis_names, period, np.tile(q, (hold + 1, 1)), zeros, zeros))
        length += hold + (0 if k else 1)
        reads.append(slice(length - read, length))
    return moves.concatenate(parts), reads


def servo_single_axis(machine: MachineConfig, true_map: ErrorMap, model: ErrorMap, stride: int = 1,
                      workers: int | None = None) -> tuple[list[SingleAxis], list[SingleAxis]]:
    """Table 6.3 through the servo: each mapped axis stepped over its range (every `stride`-th
    1 mm position) in the offline runner, without and with compensation by `model` (the
    command from Compensator.compensate), the laser reading the true tool tip (the true map at
    the true joints, every GROUND_TRUTH_DECIMATION-th step of the reading averaged) plus its
    noise; error = reading - the ideal tool tip of the position asked for. (readings with the
    laser's noise, the same without it); the runs in up to `workers` processes
    (experiments/parallel.py)."""
    from machine_ctrl.experiments import parallel
    jobs = [(machine, true_map, model if compensated else None, axis, stride)
            for axis in true_map.axes for compensated in (False, True)]
    readings = parallel.run_all(_servo_readings, jobs, workers)
    noisy, exact = [], []
    for k, axis in enumerate(true_map.axes):
        (positions, ideal, plain, plain_noise, _), (_, _, compensated, noise, fine) = readings[2 * k:2 * k + 2]
        exact.append(SingleAxis(axis, positions, plain - ideal, compensated - ideal, fine))
        noisy.append(SingleAxis(axis, positions, plain + plain_noise - ideal, compensated + noise - ideal, fine))
    return noisy, exact


def _servo_readings(machine: MachineConfig, true_map: ErrorMap, model: ErrorMap | None, axis: str, stride: int):
    """One axis, one run: (positions, ideal tips, true tips read, the laser's noise on them,
    fine-axis corrections at the readings), m."""
    truth = ErrorKinematics.from_config(machine, true_map)
    positions = measured_positions(true_map, axis)[::stride]
    reference, reads = stepped_reference(machine, axis, positions)
    command = reference
    if model is not None:
        command = Compensator.from_map(machine, model).compensate(reference)[0]
    record = run(machine, command)
    if record.fault:
        raise RuntimeError(f'Table 6.3 through the servo, {axis}: the simulated machine faulted: {record.fault}')
    rng = np.random.default_rng([machine.simulation.seed, machine.axis_names.index(axis), 63, model is not None])
    tips = np.array([truth.positions(record.true[r][::GROUND_TRUTH_DECIMATION]).mean(axis=0) for r in reads])
    at = [r.stop - 1 for r in reads]
    ideal = ErrorKinematics.from_config(machine, None).positions(reference.position[at])
    fine = [machine.axis_names.index(a) for a in machine.fine_axes]
    return (positions, ideal, tips, NOISE_DISPLACEMENT * rng.standard_normal(tips.shape),
            (command.position[at] - reference.position[at])[:, fine])


def table_6_3(results: list[SingleAxis]) -> dict:
    table = {}
    for r in results:
        unc, comp = _stats(r.uncompensated), _stats(r.compensated)
        for d in 'xyz':
            table[f'd{d}({r.axis})'] = {'mean_uncompensated': unc[d]['mean'], 'mean_compensated': comp[d]['mean'],
                                        'max_uncompensated': unc[d]['max'], 'max_compensated': comp[d]['max'],
                                        'thesis': THESIS_6_3.get((d, r.axis))}
    return table


@dataclass
class SpiralRun:
    label: str
    command: Reference              # what the servos were given
    record: RunRecord
    total: np.ndarray               # (K, 3) m at the ground-truth samples
    tracking: np.ndarray
    geometric: np.ndarray
    compensation: dict | None       # Compensation.summary() or None


def spiral_run(machine: MachineConfig, truth: ErrorKinematics, ideal: ErrorKinematics,
               reference: Reference, label: str, compensator: Compensator | None = None,
               progress=None) -> SpiralRun:
    """One offline run of `reference`, compensated by `compensator` (None: as planned)."""
    command, summary = reference, None
    if compensator is not None:
        command, comp = compensator.compensate(reference)
        summary = comp.summary()
    record = run(machine, command, progress=progress)
    k = np.arange(0, len(reference), GROUND_TRUTH_DECIMATION)
    p_ideal = ideal.positions(reference.position[k])
    p_true = truth.positions(record.true[k])
    p_cmd = truth.positions(command.position[k])
    return SpiralRun(label, command, record, p_true - p_ideal, p_true - p_cmd, p_cmd - p_ideal, summary)


def fine_stroke_use(machine: MachineConfig, runs: list[SpiralRun]) -> dict:
    """Largest |q - centre| / half stroke of each limited fine axis over the true motion of
    every run (1 would be the stroke end), and any fault."""
    out = {}
    for r in runs:
        use = {}
        for axis in machine.axes:
            if axis.drive.type == 'maglev' and axis.stroke is not None:
                lo, hi = axis.stroke
                q = r.record.column(r.record.true, axis.name)
                use[axis.name] = float(np.max(np.abs(q - 0.5 * (lo + hi))) / (0.5 * (hi - lo)))
        out[r.label] = {'max_fraction': use, 'fault': r.record.fault}
    return out


def table_6_4(runs: list[SpiralRun]) -> dict:
    return {r.label: {'total': _stats(r.total), 'tracking': _stats(r.tracking),
                      'geometric': _stats(r.geometric), 'compensation': r.compensation} for r in runs}


def write_plots(directory: Path, singles: list[SingleAxis], runs: list[SpiralRun], fine_axes) -> list[Path]:
    """Figs. 6.15-6.17 (one per axis), 6.18 (table commands for z_c) and 6.19 (spiral)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for r in singles:
        fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        for i, (ax, d) in enumerate(zip(axes, 'xyz')):
            ax.plot(r.positions * 1e3, r.uncompensated[:, i] * UM, label='uncompensated')
            ax.plot(r.positions * 1e3, r.compensated[:, i] * UM, label='compensated (fitted model)')
            ax.set_ylabel(f'd{d} [um]')
            ax.grid(True)
        axes[0].legend()
        axes[0].set_title(f'Tool-tip errors moving {r.axis} alone (thesis Figs. 6.15-6.17)')
        axes[-1].set_xlabel(f'{r.axis} [mm]')
        paths.append(_save(fig, plt, directory / f'single_axis_{r.axis}.png'))
        if r.axis == 'z_c':
            fig, ax = plt.subplots(figsize=(8, 4))
            for j, name in enumerate(fine_axes):
                unit = 'urad' if name[0] in 'abc' else 'um'
                ax.plot(r.positions * 1e3, r.fine_commands[:, j] * UM, label=f'{name} [{unit}]')
            ax.set_xlabel('z_c [mm]')
            ax.set_title('Compensating table commands, z_c alone (thesis Fig. 6.18)')
            ax.legend()
            ax.grid(True)
            paths.append(_save(fig, plt, directory / 'table_commands_z_c.png'))
    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for r in runs:
        t = np.arange(len(r.total)) * GROUND_TRUTH_DECIMATION * r.record.period
        for i, ax in enumerate(axes):
            ax.plot(t, r.total[:, i] * UM, label=r.label, linewidth=0.8)
    for ax, d in zip(axes, 'xyz'):
        ax.set_ylabel(f'P{d} error [um]')
        ax.grid(True)
    axes[0].legend()
    axes[0].set_title('Spiral tool-tip errors (thesis Fig. 6.19)')
    axes[-1].set_xlabel('t [s]')
    paths.append(_save(fig, plt, directory / 'spiral_tooltip_errors.png'))
    return paths


def _save(fig, plt, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
