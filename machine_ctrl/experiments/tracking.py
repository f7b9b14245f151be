"""Experiments of Yuen thesis section 6.3 on the simulated machine (offline runner):

* contouring (Tables 6.1 / 6.2): a circle or a square on x-y, sliding mode alone ("smc":
  the table holds its reference, no coupling) vs the dual-stage feed drive ("dsfd"). Errors
  are those of the whole machine, x = x_c + x_f and y = y_c + y_f as measured by the
  encoders (as the thesis measured them): mean |.| and max |.| of the x and y tracking
  errors and of the contour error (distance of (x, y) from the ideal contour), in um.
  Beside them: the same statistics against the simulator's true positions ("true"), and
  "at rest": the same statistics of a run that holds the contour's start point for as
  long, in the same mode, with the same simulated noise (hw_sim seeds every random source
  from simulation.seed: the same force-noise sequence). A statistic that is no larger than
  its at-rest value (a maximum: within one encoder count of it, the resolution of a
  quantized peak; a mean: not above it, as means resolve far below one count) is the
  machine's noise floor — the table's own excursion under its force noise (plant.force_noise,
  assumed in the machine config) — not a contouring result: it is listed under
  'noise_floor' and the CLI prints "floor" for it, not a figure.
  Why (issue 19, "a suspicious table"): on the square one axis is always at rest, its coarse
  stage stuck within one 40 nm count of its reference (its encoder reads zero error, so the
  coupling sends no offset) and its error is the table's noise excursion, which does not
  depend on the coarse motion: the at-rest run's table trajectory is bit-identical. Its
  peak reads 25 probe counts of 20 nm = 0.500 um, at the same steps in SMC, DSFD and at
  rest (test/test_square_artefact.py).
* frf (thesis Fig. 4.10): closed-loop frequency responses by stepped sine, servo loop
  alone (feed-forward off: the reference carries position only), lock-in (single-bin DFT)
  over whole cycles after settling; the -3 dB bandwidth is the first crossing of -3 dB,
  interpolated in log frequency. Amplitudes: COARSE_AMPLITUDE / FINE_AMPLITUDE below; the
  dual-stage "x_dual"/"y_dual" response is from the coarse reference to x_c + x_f.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from machine_ctrl.control.registry import make_law
from machine_ctrl.experiments import parallel
from machine_ctrl.identification.frequency_response import bandwidth, crossover
from machine_ctrl.model.config import MachineConfig
from hw_sim.offline import run
from machine_ctrl.model.reference import Reference
from trajectory import contours

STAT_KEYS = ('mean_x_tracking', 'mean_y_tracking', 'mean_contour',
             'max_x_tracking', 'max_y_tracking', 'max_contour')

# Yuen thesis Tables 6.1 and 6.2, converted from mm to um.
THESIS = {
    'circle': {'smc': (0.214, 0.106, 0.158, 2.67, 1.72, 2.67),
               'dsfd': (0.198, 0.0494, 0.121, 1.28, 0.377, 0.858)},
    'square': {'smc': (0.258, 0.0881, 0.0792, 5.43, 1.54, 0.759),
               'dsfd': (0.169, 0.0718, 0.0993, 2.26, 0.556, 0.862)},
}


PAIRS = (('x_c', 'x_f'), ('y_c', 'y_f'))     # thesis section 6.3: x = x_c + x_f, y = y_c + y_f


def contour_errors(record, reference: Reference, contour: contours.Contour, pairs=PAIRS,
                   source: str = 'measured') -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e_x, e_y, e_c) in m per step: reference minus the summed x and y positions, and the
    distance of (x, y) from the ideal contour; `source` 'measured' (the encoders) or 'true'
    (the simulator's true positions)."""
    positions = getattr(record, source)
    (xc, xf), (yc, yf) = pairs
    x = record.column(positions, xc) + record.column(positions, xf)
    y = record.column(positions, yc) + record.column(positions, yf)
    n = len(x)
    ex = reference.position[:n, record.axis_names.index(xc)] - x
    ey = reference.position[:n, record.axis_names.index(yc)] - y
    return ex, ey, contour.errors(x, y)


def contour_statistics(record, reference: Reference, contour: contours.Contour,
                       pairs=PAIRS, source: str = 'measured') -> dict[str, float]:
    ex, ey, ec = contour_errors(record, reference, contour, pairs, source)
    values = (np.abs(ex).mean(), np.abs(ey).mean(), ec.mean(), np.abs(ex).max(), np.abs(ey).max(), ec.max())
    return {k: float(v) * 1e6 for k, v in zip(STAT_KEYS, values)}


def encoder_count(machine: MachineConfig, pairs=PAIRS) -> float:
    """One count of the coarsest sensor summed into x and y, m (machine config
    sensor_resolution, CIRP section 2: 40 nm encoders on x_c/y_c, 20 nm on x_f/y_f)."""
    return max(machine.axes[machine.axis_names.index(a)].sensor_resolution for pair in pairs for a in pair)


def at_rest(reference: Reference) -> Reference:
    """The machine holding the reference's first point for as many steps (the noise-floor run)."""
    return Reference.hold(reference.axis_names, reference.period, reference.position[0], len(reference))


def noise_floor(stats: dict[str, float], rest: dict[str, float], count_um: float) -> list[str]:
    """The statistics no larger than what the machine reads standing still: a maximum within
    one encoder count (`count_um`) of its at-rest value (a peak of a quantized reading is
    only known to one count), a mean not above its at-rest value. Not results of the motion."""
    return [k for k in STAT_KEYS if stats[k] <= rest[k] + (count_um if k.startswith('max_') else 0.0)]


RUN_LABELS = ('smc', 'smc_at_rest', 'dsfd', 'dsfd_at_rest')     # contouring's runs, in order
# with coupled=True, also the dual stage with the cross-coupled contour control on (README
# "Contour control"), and its at-rest twin
COUPLED_LABELS = RUN_LABELS + ('ccc', 'ccc_at_rest')
MODES = {'smc': (False, False), 'dsfd': (True, False), 'ccc': (True, True)}     # (dual stage, contour control)


def run_labels(coupled: bool) -> tuple[str, ...]:
    return COUPLED_LABELS if coupled else RUN_LABELS


def contouring(machine: MachineConfig, kind: str, progress=None, steps: int | None = None,
               on_run=None, workers: int | None = None, coupled: bool = False) -> dict:
    """For kind 'circle' or 'square': {'smc': stats, 'dsfd': stats} (encoder-measured, um, as
    the thesis measured), plus 'true' {'smc', 'dsfd'} (against the simulator's true
    positions), 'at_rest' {'smc', 'dsfd'} (encoder-measured, machine holding the start point
    for as long, same mode and noise), 'noise_floor' {'smc': [keys], 'dsfd': [keys]} (the
    statistics no larger than their at-rest value, see noise_floor: not results),
    'command_use', 'encoder_count_um' and 'steps'. The four runs — 'smc', 'smc_at_rest', 'dsfd',
    'dsfd_at_rest' (:data:`RUN_LABELS`) — go in up to `workers` processes (default: the
    available CPUs; the same numbers, experiments/parallel.py); `progress('<kind> <run>',
    steps, steps)` as each is done, in that order, and `on_run(label, reference, record)`, e.g. to
    write it as a bag (``machine-ctrl experiment circle|square --record DIR`` does).
    `coupled`: also 'ccc' and 'ccc_at_rest' (:data:`COUPLED_LABELS`), the dual stage with the
    machine's cross-coupled contour control on (machine_ctrl/control/contour_coupling.py)."""
    reference, contour = getattr(contours, kind)(machine)
    steps = len(reference) if steps is None else steps
    rest_reference = at_rest(reference)
    count_um = encoder_count(machine) * 1e6
    modes = ('smc', 'dsfd', 'ccc') if coupled else ('smc', 'dsfd')
    runs = [(label, MODES[label], ref, twin) for label in modes
            for ref, twin in ((reference, False), (rest_reference, True))]
    names = [f'{label} at rest' if twin else label for label, _, _, twin in runs]
    done = None if progress is None else (lambda i: progress(f'{kind} {names[i]}', steps, steps))
    outcomes = parallel.run_all(_contour_run, [(machine, ref, mode, steps, contour, not twin, on_run is not None)
                                               for _, mode, ref, twin in runs], workers, done)
    result = {'true': {}, 'at_rest': {}, 'noise_floor': {}, 'command_use': {}, 'encoder_count_um': count_um,
              'steps': steps}
    for (label, _, ref, twin), name, (fault, measured, true, use, record) in zip(runs, names, outcomes):
        if fault:
            raise RuntimeError(f'{kind} {name}: the simulated machine faulted: {fault}')
        if twin:
            result['at_rest'][label] = measured
        else:
            result[label], result['true'][label], result['command_use'][label] = measured, true, use
        if on_run is not None:
            on_run(name.replace(' ', '_'), ref, record)
    for label in modes:
        result['noise_floor'][label] = noise_floor(result[label], result['at_rest'][label], count_um)
    return result


def _contour_run(machine: MachineConfig, reference: Reference, mode: tuple[bool, bool], steps: int,
                 contour: contours.Contour, true: bool, keep: bool):
    """One run of :func:`contouring`: (fault, measured statistics, true statistics if `true`
    else None, the largest |command| / command_limit of any axis, the record if `keep` else
    None); `mode`: (dual stage, contour control)."""
    dual_stage, contour_control = mode
    record = run(machine, reference, dual_stage=dual_stage, steps=steps, contour_control=contour_control)
    return (record.fault, contour_statistics(record, reference, contour),
            contour_statistics(record, reference, contour, source='true') if true else None,
            command_use(machine, record), record if keep else None)


def command_use(machine: MachineConfig, record) -> float:
    """The largest |command| / command_limit of any axis over a run (1: a drive at its limit)."""
    limits = np.array([machine.axis(a).drive.command_limit for a in record.axis_names])
    return float(np.abs(record.commands / limits).max())


COARSE_AMPLITUDE = 50e-6   # m: large against presliding (~4 um) so friction does not dominate
FINE_AMPLITUDE = 1e-6      # m: within the table's force limit up to ~1 kHz; also the dual-stage
                           # channels, whose motion the table carries above the coarse bandwidth


@dataclass(frozen=True)
class FrfChannel:
    name: str          # reported name
    axis: str          # axis whose reference is excited
    outputs: tuple     # axes whose measured positions sum to the output
    amplitude: float


def frf_channels(machine: MachineConfig) -> tuple[list[FrfChannel], list[FrfChannel]]:
    """(channels measured with the coupling off, channels measured with it on)."""
    alone, coupled = [], []
    fine_of = {p.coarse: p for p in machine.dual_stage}
    for axis in machine.axes:
        if axis.kind != 'linear' or axis.control is None:
            continue
        fine = axis.name in machine.fine_axes
        alone.append(FrfChannel(axis.name, axis.name, (axis.name,), FINE_AMPLITUDE if fine else COARSE_AMPLITUDE))
        pair = fine_of.get(axis.name)
        if pair is not None and pair.sign > 0:
            coupled.append(FrfChannel(f'{axis.name[0]}_dual', axis.name, (axis.name, pair.fine), FINE_AMPLITUDE))
    return alone, coupled


def _lock_in(signal: np.ndarray, phase: np.ndarray) -> complex:
    return 2.0 * np.mean(signal * np.exp(-1j * phase))


def frequency_response(machine: MachineConfig, groups: list[tuple[list[FrfChannel], bool]], frequencies,
                       settle_cycles=4, measure_cycles=6, progress=None, workers: int | None = None
                       ) -> dict[str, np.ndarray]:
    """output/reference (complex) per channel at each frequency, for each group of (channels,
    with the dual-stage coupling on?) — a group's channels excited at once; the runs in up to
    `workers` processes (default: the available CPUs; the same numbers,
    experiments/parallel.py), `progress('frf', done, runs)` as they come in."""
    jobs = [(machine, channels, f, dual_stage, settle_cycles, measure_cycles)
            for channels, dual_stage in groups for f in frequencies]
    done = None if progress is None else (lambda i: progress('frf', i + 1, len(jobs)))
    rows = iter(parallel.run_all(_frf_point, jobs, workers, done))
    gains = {}
    for channels, _ in groups:
        group = [next(rows) for _ in frequencies]
        gains.update({c.name: np.array([row[k] for row in group]) for k, c in enumerate(channels)})
    return gains


def _frf_point(machine: MachineConfig, channels: list[FrfChannel], f: float, dual_stage: bool,
               settle_cycles: int, measure_cycles: int) -> list[complex]:
    """One run of :func:`frequency_response`: each channel's response (complex) at `f` Hz."""
    fs = 1.0 / machine.control_period
    index = {n: i for i, n in enumerate(machine.axis_names)}
    period_steps = fs / f
    steps = int(round((settle_cycles + measure_cycles) * period_steps))
    t = np.arange(steps) / fs
    pos = np.tile(np.asarray(machine.home, float), (steps, 1))
    for c in channels:
        pos[:, index[c.axis]] += c.amplitude * np.sin(2 * math.pi * f * t)
    reference = Reference(machine.axis_names, machine.control_period, pos, np.zeros_like(pos), np.zeros_like(pos))
    record = run(machine, reference, dual_stage=dual_stage, feedforward=False)
    if record.fault:
        raise RuntimeError(f'frf at {f:g} Hz: the simulated machine faulted: {record.fault}')
    start = int(round(settle_cycles * period_steps))
    phase = 2 * math.pi * f * t[start:]
    gains = []
    for c in channels:
        output = sum(record.measured[start:, index[a]] for a in c.outputs)
        output = output - sum(machine.home[index[a]] for a in c.outputs)
        gains.append(_lock_in(output, phase) / (-1j * c.amplitude))    # the reference's phasor: -j A
    return gains


def frf(machine: MachineConfig, frequencies=None, progress=None, workers: int | None = None) -> dict:
    """The closed-loop responses of frf_channels (thesis Fig. 4.10): 'gain' and the -3 dB
    'bandwidth_hz' per channel; for a single axis whose law acts on the error alone
    (error_feedback, control/law.py) the open-loop crossover 'crossover_hz' from L = T/(1 - T);
    and 'design_hz', each single axis's design bandwidth (its law's design_bandwidth / 2 pi),
    the number the thesis gives for it (the table's 250 Hz is its open-loop crossover omega_m,
    Eq. 4.74; the micromill's ~30 Hz its lambda)."""
    frequencies = np.geomspace(5.0, 1500.0, 30) if frequencies is None else np.asarray(frequencies, float)
    alone, coupled = frf_channels(machine)
    groups = [(alone, False)] + ([(coupled, True)] if coupled else [])
    responses = frequency_response(machine, groups, frequencies, progress=progress, workers=workers)
    laws = {c.name: make_law(machine.axis(c.axis), machine.control_period) for c in alone}
    return {'frequencies_hz': frequencies.tolist(),
            'gain': {name: np.abs(t).tolist() for name, t in responses.items()},
            'bandwidth_hz': {name: bandwidth(frequencies, np.abs(t)) for name, t in responses.items()},
            'crossover_hz': {name: crossover(frequencies, responses[name] / (1.0 - responses[name]))
                             for name, law in laws.items() if getattr(law, 'error_feedback', False)},
            'design_hz': {name: law.design_bandwidth / (2 * math.pi) for name, law in laws.items()
                          if hasattr(law, 'design_bandwidth')}}
