"""Experiments of Yuen thesis section 6.3 on the simulated machine (offline runner):

* contouring (Tables 6.1 / 6.2): a circle or a square on x-y, sliding mode alone ("smc":
  the table holds its reference, no coupling) vs the dual-stage feed drive ("dsfd"). Errors
  are those of the whole machine, x = x_c + x_f and y = y_c + y_f as measured by the
  encoders (as the thesis measured them): mean |.| and max |.| of the x and y tracking
  errors and of the contour error (distance of (x, y) from the ideal contour), in um.
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


def contour_statistics(record, reference: Reference, contour: contours.Contour,
                       pairs=(('x_c', 'x_f'), ('y_c', 'y_f'))) -> dict[str, float]:
    (xc, xf), (yc, yf) = pairs
    x = record.column(record.measured, xc) + record.column(record.measured, xf)
    y = record.column(record.measured, yc) + record.column(record.measured, yf)
    n = len(x)
    ex = reference.position[:n, record.axis_names.index(xc)] - x
    ey = reference.position[:n, record.axis_names.index(yc)] - y
    ec = contour.errors(x, y)
    values = (np.abs(ex).mean(), np.abs(ey).mean(), ec.mean(), np.abs(ex).max(), np.abs(ey).max(), ec.max())
    return {k: float(v) * 1e6 for k, v in zip(STAT_KEYS, values)}


def contouring(machine: MachineConfig, kind: str, progress=None, steps: int | None = None,
               on_run=None) -> dict:
    """{'smc': stats, 'dsfd': stats} for kind 'circle' or 'square'. `on_run(label, reference,
    record)` is called after each run ('smc', then 'dsfd'), e.g. to write it as a bag
    (``machine-ctrl experiment circle|square --record DIR`` does)."""
    reference, contour = getattr(contours, kind)(machine)
    result = {}
    for label, dual in (('smc', False), ('dsfd', True)):
        report = None if progress is None else (lambda k, n, label=label: progress(f'{kind} {label}', k, n))
        record = run(machine, reference, dual_stage=dual, steps=steps, progress=report)
        if record.fault:
            raise RuntimeError(f'{kind} {label}: the simulated machine faulted: {record.fault}')
        result[label] = contour_statistics(record, reference, contour)
        if on_run is not None:
            on_run(label, reference, record)
    return result


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
        fine = axis.name in {p.fine for p in machine.dual_stage}
        alone.append(FrfChannel(axis.name, axis.name, (axis.name,), FINE_AMPLITUDE if fine else COARSE_AMPLITUDE))
        pair = fine_of.get(axis.name)
        if pair is not None and pair.sign > 0:
            coupled.append(FrfChannel(f'{axis.name[0]}_dual', axis.name, (axis.name, pair.fine), FINE_AMPLITUDE))
    return alone, coupled


def _lock_in(signal: np.ndarray, phase: np.ndarray) -> complex:
    return 2.0 * np.mean(signal * np.exp(-1j * phase))


def frequency_response(machine: MachineConfig, channels: list[FrfChannel], frequencies, dual_stage: bool,
                       settle_cycles=4, measure_cycles=6, progress=None) -> dict[str, np.ndarray]:
    """|output/reference| per channel at each frequency (all channels excited at once)."""
    fs = 1.0 / machine.control_period
    gains = {c.name: [] for c in channels}
    index = {n: i for i, n in enumerate(machine.axis_names)}
    for j, f in enumerate(frequencies):
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
        for c in channels:
            output = sum(record.measured[start:, index[a]] for a in c.outputs)
            output = output - sum(machine.home[index[a]] for a in c.outputs)
            gains[c.name].append(abs(_lock_in(output, phase)) / c.amplitude)
        if progress is not None:
            progress('frf', j + 1, len(frequencies))
    return {name: np.array(values) for name, values in gains.items()}


def bandwidth(frequencies, gains) -> float | None:
    """First -3 dB crossing (log-interpolated), or None if the response never drops."""
    level = 10 ** (-3 / 20)
    below = np.nonzero(np.asarray(gains) < level)[0]
    if len(below) == 0 or below[0] == 0:
        return None
    i = below[0]
    f0, f1, g0, g1 = frequencies[i - 1], frequencies[i], gains[i - 1], gains[i]
    w = (math.log(g0) - math.log(level)) / (math.log(g0) - math.log(g1))
    return float(math.exp(math.log(f0) + w * (math.log(f1) - math.log(f0))))


def frf(machine: MachineConfig, frequencies=None, progress=None) -> dict:
    frequencies = np.geomspace(5.0, 1500.0, 30) if frequencies is None else np.asarray(frequencies, float)
    alone, coupled = frf_channels(machine)
    responses = frequency_response(machine, alone, frequencies, dual_stage=False, progress=progress)
    if coupled:
        responses.update(frequency_response(machine, coupled, frequencies, dual_stage=True, progress=progress))
    return {'frequencies_hz': frequencies.tolist(),
            'gain': {name: g.tolist() for name, g in responses.items()},
            'bandwidth_hz': {name: bandwidth(frequencies, g) for name, g in responses.items()}}
