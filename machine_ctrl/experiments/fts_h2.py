"""Ding's H2-optimal fast tool servo against the PID (seed 003_edeaa855566124b7, Ch. 6) on
the machine ``fts_lathe``, offline: W alone (as section 6.4 measured it) at the thesis's
20 kHz (section 6.4.1), every noise of the plant on.

* The H2 law (machine_ctrl/control/h2.py) with the YAML's weights (the lower W_u of Fig. 6-7);
  its -3 dB bandwidth of y/r measured by a stepped sine on the simulated loop (thesis: about
  1.1 kHz, Fig. 6-10), its following error at rest over 4096 samples, RMS and p-v (0.68 nm,
  5.38 nm, section 6.4.2), and the crossover of its design loop (870 Hz for Fig. 6-5's
  weights M_u = w_bu = 1e8, section 6.3.2; printed for both weight sets).
* The PID of section 7.5.3 times a global gain K_g (section 7.4.1) at the same 20 kHz, put at
  the thesis's "similar bandwidth (1.5 kHz)" by the continuous loop of
  machine_ctrl/experiments/fts_budget.py, and a second one at the H2's measured bandwidth (the
  comparison the thesis means: "tuned with the same sampling rate and a similar bandwidth",
  its footnote 13: the bandwidth "is difficult to be tuned exactly same"): bandwidth, following RMS
  and p-v (1.19 nm, 7.65 nm).

assumed: 4096 samples per record (section 5.7.3's record, also for Ch. 6), after 0.05 s at rest;
a 1 um stepped sine for the bandwidth.

Run ``machine-ctrl experiment fts-h2 [--json] [--plots DIR]``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from hw_sim import offline
from machine_ctrl.control.h2 import h2_design
from machine_ctrl.experiments import fts_budget
from machine_ctrl.experiments.fts_freeform import sine_amplitude
from machine_ctrl.experiments.seed_rows import print_table, row_text, save_figure, seed_row, two_panels
from machine_ctrl.model.config import MachineConfig, load_machine
from machine_ctrl.model.reference import Reference
from trajectory.freeform import axis_sine

SEED = '003_edeaa855566124b7'
MACHINE = 'fts_lathe'
AXIS = 'w'
RATE_HZ = 20e3                 # Hz, the H2 servo rate, seed 003 section 6.4.1
RECORD = 4096                  # samples, assumed: the record of seed 003 section 5.7.3
SETTLE = 0.05                  # s at rest before the record, assumed: > 10 time constants of the loops
SINE = 1e-6                    # m, stepped-sine amplitude, assumed: far above the nm noise, far inside the stroke
SINE_FREQUENCIES = tuple(np.geomspace(100.0, 5000.0, 57))   # Hz, assumed: both bandwidths inside, 7 % apart
NM = 1e-9

THESIS = {
    'h2_bandwidth_hz': 1100.0,         # section 6.4.2, Fig. 6-10
    'h2_following_rms_nm': 0.68,       # section 6.4.2
    'h2_following_pv_nm': 5.38,        # section 6.4.2
    'h2_crossover_hz': 870.0,          # section 6.3.2, Fig. 6-5 (M_u = w_bu = 1e8)
    'pid_bandwidth_hz': 1500.0,        # section 6.4.2 ("a similar bandwidth (1.5 kHz)")
    'pid_following_rms_nm': 1.19,      # section 6.4.2, Fig. 6-11
    'pid_following_pv_nm': 7.65,       # section 6.4.2, Fig. 6-11
}
FIG_6_5_WEIGHTS = {'control_weight': 1e8, 'control_bandwidth': 1e8}   # section 6.3.1 ("large numbers (1e8)")


def machine_at(machine: MachineConfig, period: float, law: str, **gains) -> MachineConfig:
    """W of `machine` alone (C, X, Z left out: without the dual-stage offsets nothing couples
    them to W, and W's noise streams are seeded by its own name) at `period` with the law
    `law` (its gains section changed by `gains`)."""
    axis = machine.axis(AXIS)
    control = axis.control
    if gains:
        control = dataclasses.replace(control, **{law: dataclasses.replace(getattr(control, law), **gains)})
    axis = dataclasses.replace(axis, control=dataclasses.replace(control, law=law))
    return dataclasses.replace(machine, control_period=period, axes=(axis,), home=(machine.home[
        machine.axis_names.index(AXIS)],), dual_stage=())


def _run(machine: MachineConfig, reference: Reference):
    record = offline.run(machine, reference, dual_stage=False)
    if record.fault:
        raise ValueError(f'hw_sim stopped: {record.fault}')
    return record


def at_rest(machine: MachineConfig) -> dict:
    """Following error (reference - measured) and real error (true position) of W at rest."""
    settle = int(round(SETTLE / machine.control_period))
    record = _run(machine, axis_sine(machine, AXIS, 0.0, 1.0, (settle + RECORD - 1) * machine.control_period))
    w = machine.axis_names.index(AXIS)
    following = (record.reference[-RECORD:, w] - record.measured[-RECORD:, w])
    real = record.true[-RECORD:, w] - record.reference[-RECORD:, w]
    return {'following_rms': float(np.sqrt(np.mean((following - following.mean()) ** 2))),
            'following_pv': float(np.ptp(following)), 'real_rms': float(np.std(real)),
            'command_rms': float(np.std(record.commands[-RECORD:, w])), 'following': following}


def measured_bandwidth(machine: MachineConfig) -> dict:
    """|y/r| of W by a stepped sine on the simulated loop (y: the sampled sensor) and its
    -3 dB frequency (fts_budget.bandwidth's interpolation)."""
    period, w = machine.control_period, machine.axis_names.index(AXIS)
    settle = int(round(SETTLE / period))
    gains = []
    for f in SINE_FREQUENCIES:
        n = int(math.ceil(max(0.01, 4.0 / f) * f) / f / period)            # whole periods, >= 10 ms
        record = _run(machine, axis_sine(machine, AXIS, SINE, f, (settle + n - 1) * period))
        gains.append(sine_amplitude(record.measured[settle:, w], period, f, settle) / SINE)
    f = np.array(SINE_FREQUENCIES)
    return {'f': f, 'gain': np.array(gains), 'bandwidth_hz': fts_budget.bandwidth(f, np.array(gains))}


def design_crossover(machine: MachineConfig, **weights) -> float:
    """Crossover (|L| = 1, first) of the continuous H2 design loop L = -K P_yu (Hz)."""
    axis = machine.axis(AXIS)
    gains = dataclasses.replace(axis.control.h2, **weights)
    design = h2_design(axis, gains, machine.control_period)
    if not design.ok:
        raise ValueError(design.reason)
    loop = open_loop(design, np.geomspace(10.0, 20e3, 4000))
    below = np.nonzero(np.abs(loop['L']) < 1.0)[0]
    return float(loop['f'][below[0]]) if below.size else float('nan')


def open_loop(design, f: np.ndarray) -> dict:
    """K, P_yu (the design's stage with its Pade delay) and L = -K P_yu on f (Hz)."""
    p, k = design.plant, design.continuous
    n = p.a.shape[0] - 2
    s = 2j * math.pi * np.asarray(f)

    def response(a, b, c, d):
        eye = np.eye(a.shape[0])
        return np.array([(c @ np.linalg.solve(x * eye - a, b) + d)[0, 0] for x in s])
    kf = response(k.a, k.b, k.c, k.d)
    pf = response(p.a[:n, :n], p.b2[:n], p.c2[:, :n], np.zeros((1, 1)))
    return {'f': np.asarray(f), 'K': kf, 'P': pf, 'L': -kf * pf}


def _pid_at(machine: MachineConfig, bandwidth_hz: float) -> tuple[MachineConfig, float]:
    """W's PID times the K_g that gives `bandwidth_hz` in the continuous loop at 20 kHz."""
    plant, pid = fts_budget.loop_of_axis(machine.axis(AXIS), machine.control_period)
    tuned = fts_budget.gains_for_bandwidth(plant, bandwidth_hz, pid)
    if tuned['status'] != 'ok':
        raise ValueError(f'PID at {bandwidth_hz:.0f} Hz: {tuned["reason"]}')
    g = tuned['pid']
    return machine_at(machine, machine.control_period, 'pid', proportional=g.kp, integral=g.ki,
                      derivative=g.kd), tuned['kg']


def reproduce(machine: MachineConfig | None = None) -> dict:
    """Every figure of the module doc (seed, ours, ratio, a note where > 30 % off)."""
    machine = machine or load_machine(MACHINE)
    try:
        h2 = machine_at(machine, 1.0 / RATE_HZ, 'h2')
        h2_bw, h2_rest = measured_bandwidth(h2), at_rest(h2)
        crossover = {'fig_6_7': design_crossover(h2), 'fig_6_5': design_crossover(h2, **FIG_6_5_WEIGHTS)}
        pids = {}
        for label, target in (('thesis', THESIS['pid_bandwidth_hz']), ('h2', h2_bw['bandwidth_hz'])):
            pid, kg = _pid_at(h2, target)
            pids[label] = {'kg': kg, 'target_hz': target, **measured_bandwidth(pid), **at_rest(pid)}
    except ValueError as exc:
        return {'status': 'failed', 'reason': str(exc)}
    balance = ('the H2 optimum settles where the sensor-noise and current-noise contributions to the real '
               'error balance (section 5.7.4 finds that balance near 468 Hz with the PID); the thesis\'s 1.1 kHz '
               'needs a noise ratio or a cutting-force weight W_fc it does not print')
    resonance = ('Table 5-2\'s model has no 1645 Hz resonance, which section 6.3.2 names as what limits the PID '
                 '("caused troubles when the PID gains are further increased"); without it our PID at 1.5 kHz '
                 'keeps its phase margin and amplifies less noise')
    rows = [
        seed_row('H2 bandwidth (-3 dB, y/r), simulated', THESIS['h2_bandwidth_hz'], h2_bw['bandwidth_hz'], 'Hz', balance),
        seed_row('H2 following error RMS at rest', THESIS['h2_following_rms_nm'], h2_rest['following_rms'] / NM, 'nm'),
        seed_row('H2 following error p-v (4096 samples)', THESIS['h2_following_pv_nm'], h2_rest['following_pv'] / NM,
             'nm'),
        seed_row('H2 design crossover, W_u of Fig. 6-5', THESIS['h2_crossover_hz'], crossover['fig_6_5'], 'Hz', balance),
        seed_row('PID bandwidth, K_g for 1.5 kHz, simulated', THESIS['pid_bandwidth_hz'], pids['thesis']['bandwidth_hz'],
             'Hz', 'K_g is set on the continuous loop with the delay; the sampled loop at 20 kHz peaks higher'),
        seed_row('PID (1.5 kHz) following error RMS', THESIS['pid_following_rms_nm'],
             pids['thesis']['following_rms'] / NM, 'nm', resonance),
        seed_row('PID (1.5 kHz) following error p-v', THESIS['pid_following_pv_nm'], pids['thesis']['following_pv'] / NM,
             'nm', resonance),
        seed_row('H2 / PID (1.5 kHz) following RMS', THESIS['h2_following_rms_nm'] / THESIS['pid_following_rms_nm'],
             h2_rest['following_rms'] / pids['thesis']['following_rms'], '1', resonance),
    ]
    runs = {'h2': {'bandwidth': h2_bw, **h2_rest, 'crossover_hz': crossover},
            'pid_1500': pids['thesis'], 'pid_same_bandwidth': pids['h2']}
    return {'status': 'ok', 'reason': '', 'machine': machine.name, 'rows': rows, 'runs': runs}


def format_table(result: dict) -> str:
    if result.get('status') != 'ok':
        return f'FTS H2 vs PID failed: {result.get("reason")}'
    lines = [f'Ding Ch. 6 H2-optimal vs PID (seed {SEED}) on {result["machine"]}, W alone at 20 kHz, noise on',
             f'{"figure":<44} {"seed":>8} {"ours":>9} {"ratio":>7}  unit']
    lines += [row_text(r, 44) for r in result['rows']]
    runs = result['runs']
    h2, same = runs['h2'], runs['pid_same_bandwidth']
    lines.append(f'H2: real positioning error {h2["real_rms"] / NM:.3f} nm RMS; design crossover with the W_u of '
                 f'Fig. 6-7 {h2["crossover_hz"]["fig_6_7"]:.0f} Hz')
    lines.append(f'PID at the H2\'s bandwidth (K_g {same["kg"]:.3g} from the continuous loop; simulated first -3 dB '
                 f'at {same["bandwidth_hz"]:.0f} Hz: |y/r| hovers near -3 dB around the 445 Hz mode): '
                 f'following {same["following_rms"] / NM:.3f} nm RMS, {same["following_pv"] / NM:.2f} nm p-v, '
                 f'real {same["real_rms"] / NM:.3f} nm RMS (H2: {h2["following_rms"] / NM:.3f}, '
                 f'{h2["real_rms"] / NM:.3f})')
    return '\n'.join(lines)


def plots(result: dict, directory) -> list[str]:
    """Closed-loop |y/r| of both laws (the stepped sines) and the spectra of their following
    errors (Fig. 6-12). Returns the paths written."""
    if result.get('status') != 'ok':
        return []
    runs = result['runs']
    plt, fig, (ax, axs) = two_panels(directory)
    for key, label in (('h2', 'H2'), ('pid_1500', 'PID 1.5 kHz'), ('pid_same_bandwidth', 'PID, H2 bandwidth')):
        r = runs[key]
        bw = r['bandwidth'] if key == 'h2' else r
        ax.semilogx(bw['f'], 20 * np.log10(bw['gain']), 'o-', ms=3, label=f'{label} ({bw["bandwidth_hz"]:.0f} Hz)')
        spectrum = np.abs(np.fft.rfft(r['following'] * np.hanning(RECORD))) * 2 / np.sum(np.hanning(RECORD))
        axs.loglog(np.fft.rfftfreq(RECORD, 1.0 / RATE_HZ)[1:], spectrum[1:] / NM, lw=0.8,
                   label=f'{label} ({r["following_rms"] / NM:.2f} nm RMS)')
    ax.axhline(-3.0103, color='0.5', lw=0.8)
    ax.set_xlabel('frequency [Hz]')
    ax.set_ylabel('|y/r| [dB] (stepped sine, simulated)')
    axs.set_xlabel('frequency [Hz]')
    axs.set_ylabel('following error amplitude [nm] (Fig. 6-12)')
    ax.legend(fontsize=8)
    axs.legend(fontsize=8)
    return [save_figure(plt, fig, directory, 'fts_h2.png')]


def main(argv=None) -> int:
    return print_table(reproduce, format_table)


if __name__ == '__main__':
    raise SystemExit(main())
