"""Ding's acceleration feedback (seed 003_edeaa855566124b7, Ch. 7) on the machine
``fts_lathe``, offline: W alone at 199.6 kHz (section 7.5.2), every noise on, the PID of
section 7.5.3 with the cascade acceleration loop of Fig. 7-6 (machine_ctrl/control/pid.py)
reading the simulated accelerometer (Table 7-2, hw_sim/flexure.py).

* Dynamic compliance X/dF (Eq. 7-9, Table 7-1) by a stepped-sine force on the moving mass:
  K_a = 0 and 1 with the PID gains fixed (Fig. 7-13), K_a = 4 with the PID gains times
  K_g (Fig. 7-14), each beside Eq. (7-9) for the single body (M = m1 + m2, C = c2, K = k2) the
  equation assumes.
* The intermittent cut of section 7.6 (Table 7-3: 250 rpm, half of each revolution in the
  cut): a step of force on the tool when it enters the cut and off when it leaves. K_a = 0,
  0.5, 1, 4, the PID gains times K_g = (M + K_a H_acc H_I K_T)/M (section 7.4.1; printed
  inverted, seed-notes.md), M = m1 + m2 of Table 5-2. The peak following error at the entry
  (thesis: 75 nm at K_a = 0 down to 25 nm at K_a = 4), the peak tool deviation beside the
  surface form errors of the four tracks (106, 68, 42, 27 nm), the peak's duration (about
  6 ms) and the following error at rest (Fig. 7-12: the accelerometer's noise grows with K_a).

Calibrated: the cutting force, which the thesis does not state (Table 7-3 gives the cut, not
the force): its step is the one level, solved so that the K_a = 0 peak following error is
the thesis's 75 nm; every other figure is predicted with it.

The accelerometer's sensitivity H_acc = 9.356e-3 V per m/s^2 is the nominal 1000 mV/g of
Table 7-2 over the 10.8995 that section 7.5.1 multiplies the acceleration response by to match
the displacement response. Read instead as 1/10.8995 V per m/s^2 (the nominal within its
-10 %), the acceleration loop's gain at K_a = 4 is 18 and the loop is unstable in this model,
while the thesis ran K_a = 4; ``reproduce`` prints that reading's result too.

assumed: 0.02 s at rest before the cut (> 3 peak durations), 0.06 s after the exit; a 0.2 N
stepped-sine force (0.1 um at 100 Hz, 1 nm at 20 kHz: above the nm noise); lines from 50 Hz
to 20 kHz.

Run ``machine-ctrl experiment fts-accel [--json] [--plots DIR]``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from hw_sim import offline
from machine_ctrl.experiments import fts_h2
from machine_ctrl.experiments.fts_freeform import sine_amplitude
from machine_ctrl.experiments.seed_rows import print_table, row_text, save_figure, seed_row, two_panels
from machine_ctrl.model.config import MachineConfig, load_machine
from trajectory.freeform import axis_sine

SEED = '003_edeaa855566124b7'
MACHINE = 'fts_lathe'
AXIS = 'w'
NM = 1e-9
CUT_RPM = 250.0               # seed 003 Table 7-3
BEFORE, AFTER = 0.02, 0.06    # s at rest before the entry and after the exit, assumed (module doc)
CUT_GAINS = (0.0, 0.5, 1.0, 4.0)                 # K_a of the four tracks, seed 003 section 7.6.2
COMPLIANCE_SETS = ((0.0, False), (1.0, False), (4.0, True))   # (K_a, PID x K_g): Figs. 7-13, 7-14
FORCE_AMPLITUDE = 0.2         # N, stepped sine, assumed
FREQUENCIES = tuple(np.geomspace(50.0, 20e3, 16))   # Hz, assumed
SETTLE = 0.02                 # s per line, assumed
NOMINAL_SENSITIVITY = 1.0 / 9.80665                 # V per m/s^2: 1000 mV/g, seed 003 Table 7-2
MATCH_GAIN = 10.8995                                # seed 003 section 7.5.1, Fig. 7-11

THESIS = {
    'peak_ka0_nm': 75.0,          # section 7.6.2, Fig. 7-17 a) (the calibration figure)
    'peak_ka4_nm': 25.0,          # section 7.6.2, Fig. 7-17 d)
    'peak_duration_ms': 6.0,      # section 7.6.2 ("approximately 6 milliseconds")
    'surface_nm': {0.0: 106.0, 0.5: 68.0, 1.0: 42.0, 4.0: 27.0},   # section 7.6.2, Figs. 7-18, 7-19
}
CALIBRATION = 'peak_ka0_nm'


def mass_factor(machine: MachineConfig, ka: float, sensitivity: float | None = None) -> float:
    """K_g = (M + K_a H_acc H_I K_T)/M at DC (section 7.4.1, seed-notes.md), M = m1 + m2 as the
    controllers know it (the drive's mass: a gain setting is a design step), H_acc the law's or
    `sensitivity`."""
    axis = machine.axis(AXIS)
    h_acc = axis.control.pid.accelerometer_sensitivity if sensitivity is None else sensitivity
    m = axis.drive.mass
    return (m + ka * h_acc * axis.drive.amplifier_gain * axis.drive.force_constant) / m


def w_alone(machine: MachineConfig, ka: float, scaled: bool, sensitivity: float | None = None) -> MachineConfig:
    """The machine with only W, its PID with K_a = `ka` (and the gains times K_g when `scaled`;
    `sensitivity`: another H_acc for the law and the accelerometer both)."""
    if sensitivity is not None:
        axis = machine.axis(AXIS)
        accel = dataclasses.replace(axis.plant.accelerometer, sensitivity=sensitivity)
        axis = dataclasses.replace(axis, plant=dataclasses.replace(axis.plant, accelerometer=accel))
        machine = dataclasses.replace(machine, axes=tuple(axis if a.name == AXIS else a for a in machine.axes))
    g = machine.axis(AXIS).control.pid
    sensed = g.accelerometer_sensitivity if sensitivity is None else sensitivity
    kg = mass_factor(machine, ka, sensed) if scaled else 1.0
    return fts_h2.machine_at(machine, machine.control_period, 'pid', proportional=g.proportional * kg,
                             integral=g.integral * kg, derivative=g.derivative * kg, acceleration_gain=ka,
                             accelerometer_sensitivity=sensed)


def _run(machine: MachineConfig, duration: float, force: np.ndarray):
    record = offline.run(machine, axis_sine(machine, AXIS, 0.0, 1.0, duration), forces={AXIS: force})
    if record.fault:
        raise ValueError(f'hw_sim stopped: {record.fault}')
    return record


def intermittent_cut(machine: MachineConfig, force: float) -> dict:
    """The section 7.6 cut on `machine` (W alone): following error and tool deviation at the
    entry, the peak's duration, the following error at rest before it."""
    period = machine.control_period
    cut = 0.5 * 60.0 / CUT_RPM                                 # s: half a revolution in the cut
    entry, exit_ = int(round(BEFORE / period)), int(round((BEFORE + cut) / period))
    steps = exit_ + int(round(AFTER / period))
    profile = np.zeros(steps)
    profile[entry:exit_] = force
    record = _run(machine, (steps - 1) * period, profile)
    following = record.reference[:, 0] - record.measured[:, 0]
    deviation = record.true[:, 0] - record.reference[:, 0]
    window = slice(entry, entry + int(round(0.02 / period)))
    peak = float(np.max(np.abs(following[window])))
    above = np.nonzero(np.abs(following[window]) > 0.1 * peak)[0]
    return {'peak_following': peak, 'peak_deviation': float(np.max(np.abs(deviation[window]))),
            'duration': float((above[-1] + 1) * period) if above.size else 0.0,
            'rest_rms': float(np.std(following[:entry])),
            'following': following, 'entry': entry, 'exit': exit_}


def compliance(machine: MachineConfig, frequencies=FREQUENCIES) -> np.ndarray:
    """|X/dF| (m/N) of W's tool position by a stepped-sine force (noise on)."""
    period = machine.control_period
    settle = int(round(SETTLE / period))
    out = []
    for f in frequencies:
        n = int(math.ceil(max(0.01, 4.0 / f) * f) / f / period)         # whole periods, >= 10 ms
        t = np.arange(settle + n) * period
        record = _run(machine, (settle + n - 1) * period, FORCE_AMPLITUDE * np.sin(2 * math.pi * f * t))
        out.append(sine_amplitude(record.true[settle:, 0], period, f, settle) / FORCE_AMPLITUDE)
    return np.array(out)


def eq_7_9(machine: MachineConfig, f: np.ndarray) -> np.ndarray:
    """Eq. (7-9) for W's gains and the single body M = m1 + m2, C = c2, K = k2, with H_I, H_capa
    and H_acc the axis's current loop, sensor and accelerometer low-passes; the loop delay and
    half a period of the zero-order hold are put on H_I (the equation has no delay)."""
    axis = machine.axis(AXIS)
    g, d, p = axis.control.pid, axis.drive, axis.plant
    s = 2j * math.pi * np.asarray(f, dtype=float)

    def low_pass(mode):
        return mode.omega ** 2 / (s * s + 2 * mode.zeta * mode.omega * s + mode.omega ** 2)
    h_i = d.amplifier_gain * low_pass(p.current_loop) * np.exp(-s * (p.loop_delay + 0.5 * machine.control_period))
    h_capa = g.sensitivity * low_pass(p.sensor_bandwidth)
    h_acc = g.accelerometer_sensitivity * low_pass(p.accelerometer.bandwidth)
    h_a = 1.0 if g.acceleration_filter == 0 else g.acceleration_filter / (s + g.acceleration_filter)
    kt = d.force_constant
    mass = d.mass + h_a * g.acceleration_gain * h_acc * h_i * kt
    damping = d.damping + g.derivative / (g.derivative_filter * s + 1) * h_capa * h_i * kt
    spring = p.flexure.stiffness + g.proportional * h_capa * h_i * kt
    super_spring = g.integral * h_capa * h_i * kt
    return 1.0 / (mass * s * s + damping * s + spring + super_spring / s)


def reproduce(machine: MachineConfig | None = None, frequencies=FREQUENCIES) -> dict:
    """Every figure of the module doc (seed, ours, ratio, a note where > 30 % off)."""
    machine = machine or load_machine(MACHINE)
    try:
        base = w_alone(machine, 0.0, False)
        unit = intermittent_cut(base, 1.0)
        force = THESIS[CALIBRATION] * NM / unit['peak_following']        # the one calibrated level
        cuts = {ka: intermittent_cut(w_alone(machine, ka, True), force) for ka in CUT_GAINS}
        curves = {}
        for ka, scaled in COMPLIANCE_SETS:
            m = w_alone(machine, ka, scaled)
            curves[f'ka={ka:g}{" x Kg" if scaled else ""}'] = {
                'ka': ka, 'kg': mass_factor(m, ka) if scaled else 1.0, 'f': np.asarray(frequencies),
                'simulated': compliance(m, frequencies), 'eq_7_9': np.abs(eq_7_9(m, frequencies))}
        other = 1.0 / MATCH_GAIN
        try:
            other_cut = intermittent_cut(w_alone(machine, 4.0, True, sensitivity=other), force)
            other_reading = {'sensitivity': other, 'peak_following': other_cut['peak_following'],
                             'rest_rms': other_cut['rest_rms'], 'fault': None}
        except ValueError as exc:
            other_reading = {'sensitivity': other, 'fault': str(exc)}
    except ValueError as exc:
        return {'status': 'failed', 'reason': str(exc)}
    c0, c4 = cuts[0.0], cuts[4.0]
    surface = THESIS['surface_nm']
    rows = [
        seed_row('cut: peak following error, K_a = 4', THESIS['peak_ka4_nm'], c4['peak_following'] / NM, 'nm'),
        seed_row('cut: peak duration, K_a = 0 (10 % of the peak)', THESIS['peak_duration_ms'], c0['duration'] * 1e3, 'ms',
             'the error decays with the PID\'s integral action; the thesis reads "approximately 6 ms" off Fig. 7-17 '
             'without saying where a peak ends'),
    ]
    for ka in CUT_GAINS[1:]:
        rows.append(seed_row(f'cut: tool deviation K_a = {ka:g} / K_a = 0 (surface)', surface[ka] / surface[0.0],
                         cuts[ka]['peak_deviation'] / c0['peak_deviation'], '1',
                         'the surface form is the tool deviation over the whole track, averaged over 0.2 mm '
                         '(section 7.6.2); here the peak deviation at the entry'))
    runs = {'force_n': force, 'period': base.control_period, 'cuts': cuts, 'compliance': curves,
            'other_sensitivity_reading': other_reading,
            'kg': {ka: mass_factor(base, ka) for ka in CUT_GAINS}}
    return {'status': 'ok', 'reason': '', 'machine': machine.name, 'rows': rows, 'runs': runs}


def format_table(result: dict) -> str:
    if result.get('status') != 'ok':
        return f'FTS acceleration feedback failed: {result.get("reason")}'
    runs = result['runs']
    lines = [f'Ding Ch. 7 acceleration feedback (seed {SEED}) on {result["machine"]}, W alone at 199.6 kHz, noise on',
             f'calibrated: cutting force {runs["force_n"] * 1e3:.1f} mN against {CALIBRATION} = {THESIS[CALIBRATION]:g} nm',
             f'{"figure":<48} {"seed":>8} {"ours":>9} {"ratio":>7}  unit']
    lines += [row_text(r) for r in result['rows']]
    lines.append(f'{"K_a":>5} {"K_g":>6} {"peak following nm":>18} {"peak deviation nm":>18} {"at rest nm RMS":>15}')
    for ka, c in runs['cuts'].items():
        lines.append(f'{ka:>5g} {runs["kg"][ka]:>6.3f} {c["peak_following"] / NM:>18.1f} {c["peak_deviation"] / NM:>18.1f} '
                     f'{c["rest_rms"] / NM:>15.3f}')
    for name, c in runs['compliance'].items():
        dev = 20 * np.log10(c['simulated'] / c['eq_7_9'])
        lines.append(f'compliance {name}: simulated vs Eq. (7-9) single body {dev.min():+.1f} .. {dev.max():+.1f} dB '
                     f'(the 445 Hz mode of m4 is not in Eq. 7-9); at 100 Hz, 1 kHz, 5 kHz: '
                     + ', '.join(f'{np.interp(fx, c["f"], c["simulated"]) / NM:.3g}' for fx in (100, 1e3, 5e3))
                     + ' nm/N')
    lines.append('at rest the following error hardly changes with K_a: the accelerometer noise here is Table 7-2\'s '
                 'laboratory 0.4 ug/sqrt(Hz); the on-site noise of Fig. 7-10 (larger, "randomly distributed peaks"), '
                 'which makes it the major error source at K_a = 4 in Fig. 7-12, is not given in numbers')
    o = runs['other_sensitivity_reading']
    lines.append(f'H_acc read as 1/{MATCH_GAIN} V per m/s^2 ({o["sensitivity"]:.4g}): K_a = 4 with its K_g '
                 + (f'stops the machine ({o["fault"]})' if o['fault'] else
                    f'peaks at {o["peak_following"] / NM:.0f} nm, {o["rest_rms"] / NM:.1f} nm RMS at rest (unstable, '
                    'bounded by the DAC)'))
    return '\n'.join(lines)


def plots(result: dict, directory) -> list[str]:
    """Dynamic compliance (Figs. 7-13, 7-14) and the cut's following errors (Fig. 7-17)."""
    if result.get('status') != 'ok':
        return []
    runs = result['runs']
    plt, fig, (ax, axc) = two_panels(directory)
    for (name, c), colour in zip(runs['compliance'].items(), ('tab:blue', 'tab:orange', 'tab:green')):
        ax.loglog(c['f'], c['simulated'], 'o', color=colour, ms=3, label=f'{name} simulated')
        ax.loglog(c['f'], c['eq_7_9'], '-', color=colour, lw=1, label=f'{name} Eq. (7-9)')
    ax.set_xlabel('frequency [Hz]')
    ax.set_ylabel('|X/dF| [m/N]')
    ax.legend(fontsize=7)
    period = runs['period']
    for ka, c in runs['cuts'].items():
        t = (np.arange(len(c['following'])) - c['entry']) * period * 1e3
        axc.plot(t, c['following'] / NM, lw=0.7, label=f'K_a = {ka:g} ({c["peak_following"] / NM:.0f} nm)')
    axc.set_xlabel('time from the entry [ms]')
    axc.set_ylabel('following error [nm] (Fig. 7-17)')
    axc.legend(fontsize=7)
    return [save_figure(plt, fig, directory, 'fts_accel.png')]


def main(argv=None) -> int:
    return print_table(reproduce, format_table)


if __name__ == '__main__':
    raise SystemExit(main())
