"""Ding's freeform cuts (seed 003_edeaa855566124b7, Ch. 8) on the machine ``fts_lathe``,
offline (hw_sim/offline.py): spindle-slaved commands of trajectory/freeform.py into the C, X
and W servos, every axis simulated at 199.6 kHz with its noise. Per cut the figure the thesis
reports, ours beside it, and what the linear loop of the section 5.7 budget
(machine_ctrl/experiments/fts_budget.py) predicts for the same plant and gains.

Cuts (each a short stretch of the real one: the figures are local, and the loop settles
in tens of ms):
* sinusoidal grid at the edge (section 8.5.4, Table 8-5: +-5 um, 1 mm wavelengths, 60 rpm,
  5 um/rev) at r = 25 mm: tool p-v over commanded p-v (the thesis: 11.18 um measured for
  10 um nominal at the edge, "about 200 Hz");
* the same grid near the centre, at the radius where its fastest component is 20 Hz: the
  largest following error (the thesis: "within 25 nm when the motion frequency is around
  20 Hz");
* lenslet (section 8.5.2, Table 8-3): W a 100 Hz sine of 5 um (the text's "nominal motion
  amplitude is 5 um"; Table 8-3 prints 10 um: seed-notes.md), the tool's amplitude over the
  command's in dB (the thesis: 0.6 dB overshoot at 100 Hz, 5.2 um);
* the lenslet cut's cutting force (section 5.7.5, Fig. 5-19): the same 100 Hz motion, the
  material cut at the far end of each stroke to half the amplitude (section 8.5.2), the force
  on the tool proportional to the depth engaged (assumed: the thesis gives the measured force
  only as a plot). Its level is the one calibrated figure: the 295 nm largest deviation the
  thesis simulated from its measured force; predicted with it: the deviation's overshoot the
  other way once the cut ends (the thesis's simulation: 180 nm), and the largest following
  error of the cut, motion and force together (measured: 266 nm). The deviation is the
  difference of two runs with the same seed, with and without the force (the noise cancels
  to within the ADC's and the DAC's quantization); the loop's column is its periodic steady state from the budget's force response
  at the harmonics of 100 Hz (an FFT of the force, no time stepping);
* beam integrator (section 8.5.3, Table 8-4: R = 100 mm, L = 2 mm, 120 rpm, 5 um/rev) at
  r = 25 mm (the 50 mm workpiece): the largest following error, at the cell borders (the
  thesis: "around 0.4 um overshoot at every transition corner"). Its kinks need more than
  W's acceleration limit; run as the thesis ran it (no limit), the peak is printed.

assumed: r = 25 mm for the edge cuts (the 50 mm workpiece of section 8.5.3; the grid's is
not stated); settled = after the first 25 % of each run (the sine and the feed start at full
speed from rest).

Run ``machine-ctrl experiment fts-freeform [--json]``.
"""
from __future__ import annotations

import math

import numpy as np

from hw_sim import offline
from machine_ctrl.experiments import fts_budget
from machine_ctrl.experiments.seed_rows import print_table, save_figure, seed_row, two_panels
from machine_ctrl.model.config import MachineConfig, load_machine
from trajectory.freeform import BeamIntegrator, SinusoidalGrid, Turning, axis_sine, freeform_reference

SEED = '003_edeaa855566124b7'
MACHINE = 'fts_lathe'
RPM = 2 * math.pi / 60.0           # rad/s per rpm
EDGE_RADIUS = 25e-3                # m, assumed (module doc)
SETTLE = 0.25                      # fraction of each run left out (module doc)
NM, UM = fts_budget.NM, 1e-6       # m per nm, per um (figures are printed in nm and um)

THESIS = {
    'grid_edge_pv_ratio': 11.18 / 10.0,     # section 8.5.4: 11.18 um measured for 10 um nominal at the edge
    'grid_20hz_following_nm': 25.0,         # section 8.5.4 / 8.6: within 25 nm at ~20 Hz
    'lenslet_100hz_overshoot_db': 0.6,      # section 8.5.2: 0.6 dB at 100 Hz (5.2 um for 5 um)
    'beam_transition_overshoot_um': 0.4,    # section 8.5.3, Fig. 8-15: ~0.4 um at every transition corner
    'lenslet_force_deviation_nm': 295.0,    # section 5.7.5, Fig. 5-19: simulated from the measured force (calibration)
    'lenslet_force_overshoot_nm': 180.0,    # section 5.7.5: "a 180 nm overshoot in the opposite direction"
    'lenslet_following_nm': 266.0,          # section 5.7.5, Fig. 5-19: measured largest following error
}
LENSLET_HZ, LENSLET_AMPLITUDE = 100.0, 5e-6   # Table 8-3; the text's 5 um nominal amplitude (seed-notes.md)
PLOT_PERIODS = 3                              # lenslet periods in the plot
LENSLET_DEPTH = LENSLET_AMPLITUDE / 2         # m: "depth of cut ... half of the sinusoidal amplitude" (section 8.5.2)


def _settled(record, column: int):
    start = int(len(record.reference) * SETTLE)
    ref = record.reference[start:, column]
    return ref, record.measured[start:, column], record.true[start:, column], start


def sine_amplitude(signal_: np.ndarray, period: float, frequency: float, start: int) -> float:
    """Amplitude of the `frequency` component (least squares with an offset)."""
    t = (start + np.arange(len(signal_))) * period
    w = 2 * math.pi * frequency
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    a, b, _ = np.linalg.lstsq(basis, signal_, rcond=None)[0]
    return math.hypot(a, b)


def _loop(machine: MachineConfig, frequency: float, heavy: bool = False) -> dict:
    """|T| and |S| of the budget's continuous loop at `frequency` for the machine's W gains
    (`heavy`: with the 0.175 kg moving mass of section 5.7.3)."""
    plant, pid = fts_budget.loop_of_axis(machine.axis('w'), machine.control_period)
    plant = fts_budget.heavy_plant(plant) if heavy else plant
    r = fts_budget.responses(plant, pid, np.array([frequency]))
    return {'T': float(abs(r['T'][0])), 'S': float(abs(r['S'][0]))}


def _row(name, seed, ours, unit, predicted=None, note=''):
    """A seed row (ratio, > 30 % off with its note) plus the loop's prediction."""
    return {**seed_row(name, seed, ours, unit, note), 'predicted': predicted}


def _reference(result):
    if not result.ok:
        raise ValueError(f'{result.status}: {result.reason}')
    return result.reference


def _run(machine, reference):
    record = offline.run(machine, reference)
    if record.fault:
        raise ValueError(f'hw_sim stopped: {record.fault}')
    return record


def lenslet_force(position: np.ndarray) -> np.ndarray:
    """Force (N per N at full depth) on the tool where the sine reaches past A - depth: the
    depth engaged over the full depth, pushing the tool back out of the material (module doc)."""
    return -np.clip(position - (LENSLET_AMPLITUDE - LENSLET_DEPTH), 0.0, None) / LENSLET_DEPTH


def lenslet_steady_state(machine: MachineConfig, level: float, samples: int = 4000) -> np.ndarray:
    """The budget's prediction of the force's deviation of the measured position over one
    100 Hz period in steady state: the force's harmonics times -following['force'](j w_k)
    (machine_ctrl/experiments/fts_budget.py, exact delay), back by inverse FFT."""
    plant, pid = fts_budget.loop_of_axis(machine.axis('w'), machine.control_period)
    t = np.arange(samples) / (samples * LENSLET_HZ)
    force = level * lenslet_force(LENSLET_AMPLITUDE * np.sin(2 * math.pi * LENSLET_HZ * t))
    spectrum = np.fft.rfft(force)
    harmonics = LENSLET_HZ * np.arange(1, len(spectrum))
    response = np.concatenate([[0.0], -fts_budget.responses(plant, pid, harmonics)['following']['force']])
    return np.fft.irfft(spectrum * response, n=samples)       # the DC force gives none: the integral


def _lenslet_force_rows(machine: MachineConfig, reference, free) -> tuple[list, dict]:
    """The Fig. 5-19 rows (module doc): a unit run gives the level, a run at that level the figures."""
    w, period = machine.axis_names.index('w'), machine.control_period
    shape = lenslet_force(reference.position[:, w] - machine.home[w])
    start = int(len(shape) * SETTLE)

    def deviation(level):
        forced = offline.run(machine, reference, forces={'w': level * shape})
        if forced.fault:
            raise ValueError(f'hw_sim stopped: {forced.fault}')
        return (forced.measured[:, w] - free.measured[:, w])[start:], forced
    unit, _ = deviation(1.0)
    level = THESIS['lenslet_force_deviation_nm'] * NM / np.abs(unit).max()
    dev, forced = deviation(level)
    sign = np.sign(dev[np.abs(dev).argmax()])
    following = (forced.reference[:, w] - forced.measured[:, w])[start:]
    loop = lenslet_steady_state(machine, level)
    loop_sign = np.sign(loop[np.abs(loop).argmax()])
    engaged = shape[start:] < 0
    peak = int(np.abs(dev).argmax())                 # the largest force of that stroke: within a period before
    first = max(0, peak - int(round(1.0 / (LENSLET_HZ * period))))
    lag = (peak - first - int(np.abs(shape[start + first:start + peak + 1]).argmax())) * period
    rows = [
        _row('lenslet force: largest deviation [calibration]', THESIS['lenslet_force_deviation_nm'],
             float(np.abs(dev).max()) / NM, 'nm', float(np.abs(loop).max()) / NM),
        _row('lenslet force: overshoot after the cut', THESIS['lenslet_force_overshoot_nm'],
             float(max(0.0, (-sign * dev).max())) / NM, 'nm', float(max(0.0, (-loop_sign * loop).max())) / NM,
             'a force proportional to the depth engaged (assumed) rises and falls smoothly with the sine; the '
             "thesis's measured force (Fig. 5-19, a plot) drops at the cut's end, which rings the loop more"),
        _row('lenslet: largest following error in the cut', THESIS['lenslet_following_nm'],
             float(np.abs(following[engaged]).max()) / NM, 'nm', None,
             f'motion and force together: the 100 Hz, 5 um motion alone leaves |S| A = '
             f'{_loop(machine, LENSLET_HZ)["S"] * LENSLET_AMPLITUDE / NM:.0f} nm of following error; the thesis '
             'measured with its own set-up (mass and gains of Ch. 8 not stated)'),
    ]
    last = int(round(PLOT_PERIODS / (LENSLET_HZ * period)))      # the plot's window: the last periods
    return rows, {'force_peak_n': float(level), 'deviation_lag_ms': float(lag * 1e3), 'plot_first_row': len(shape) - last,
                  'deviation': dev[-last:], 'force': level * shape[-last:], 'loop': loop}


def reproduce(machine: MachineConfig | None = None) -> dict:
    """Every figure of the module doc (seed, ours, ratio, the loop's prediction, a note > 30 % off)."""
    machine = machine or load_machine(MACHINE)
    w = machine.axis_names.index('w')
    period = machine.control_period
    grid = SinusoidalGrid()
    rows, runs = [], {}
    try:
        # grid at the edge
        edge = freeform_reference(machine, grid, Turning(60 * RPM, 5e-6, EDGE_RADIUS, 0.1))
        ref, _, true, _ = _settled(_run(machine, _reference(edge)), w)
        edge_hz = EDGE_RADIUS * 60 * RPM / grid.wavelength_x
        runs['grid_edge'] = {'fastest_component_hz': edge_hz, 'w_peaks': edge.peaks['w']}
        rows.append(_row('grid p-v, tool / command, r = 25 mm', THESIS['grid_edge_pv_ratio'],
                         float(np.ptp(true) / np.ptp(ref)), '1', _loop(machine, edge_hz)['T'],
                         'the overshoot of |T| near 150-220 Hz depends on the moving mass and gains of the '
                         'Ch. 8 set-up, which the thesis does not state (Table 5-2 mass, Ch. 7 gains here)'))
        # grid where its fastest component is 20 Hz
        r20 = 20.0 * grid.wavelength_x / (60 * RPM)
        centre = freeform_reference(machine, grid, Turning(60 * RPM, 5e-6, r20, 0.25))
        ref, measured, _, _ = _settled(_run(machine, _reference(centre)), w)
        runs['grid_20hz'] = {'radius_m': r20, 'w_peaks': centre.peaks['w'], 'following': ref - measured}
        rows.append(_row('grid max following error at <= 20 Hz', THESIS['grid_20hz_following_nm'],
                         float(np.abs(ref - measured).max()) / NM, 'nm',
                         _loop(machine, 20.0)['S'] * 2 * grid.amplitude_x / NM,
                         "the grid's x and y waves add up to +-10 um; one 5 um wave at 20 Hz alone gives "
                         f"|S| A = {_loop(machine, 20.0)['S'] * grid.amplitude_x / NM:.1f} nm. The thesis does not "
                         'say which radius or wave its "around 20 Hz" trace is'))
        # lenslet: 100 Hz, 5 um
        lenslet = axis_sine(machine, 'w', LENSLET_AMPLITUDE, LENSLET_HZ, 0.1)
        record = _run(machine, lenslet)
        ref, _, true, start = _settled(record, w)
        ratio = sine_amplitude(true, period, 100.0, start) / sine_amplitude(ref, period, 100.0, start)
        rows.append(_row('lenslet 100 Hz overshoot, tool / command', THESIS['lenslet_100hz_overshoot_db'],
                         20 * math.log10(ratio), 'dB', 20 * math.log10(_loop(machine, 100.0)['T']),
                         "Table 5-2's 0.074 kg with the Ch. 7 gains peaks less than the thesis's Ch. 8 loop; with "
                         'the 0.175 kg of section 5.7.3 the loop gives '
                         f'{20 * math.log10(_loop(machine, 100.0, heavy=True)["T"]):.2f} dB. Ch. 8 states neither '
                         'its moving mass nor its gains'))
        force_rows, runs['lenslet_force'] = _lenslet_force_rows(machine, lenslet, record)
        rows += force_rows
        # beam integrator at the edge, no limits (its kinks)
        beam = freeform_reference(machine, BeamIntegrator(), Turning(120 * RPM, 5e-6, EDGE_RADIUS, 0.05),
                                  check_limits=False)
        ref, measured, _, _ = _settled(_run(machine, _reference(beam)), w)
        runs['beam'] = {'w_peaks': beam.peaks['w'], 'w_acceleration_limit': machine.axis('w').limits.acceleration}
        rows.append(_row('beam integrator max following error', THESIS['beam_transition_overshoot_um'],
                         float(np.abs(ref - measured).max()) / UM, 'um', None,
                         'the slope jump at a cell border depends on where the tool crosses it (corner or edge, '
                         'the feed position); Fig. 8-15 shows one segment'))
    except ValueError as exc:
        return {'status': 'failed', 'reason': str(exc)}
    runs['period'] = period
    return {'status': 'ok', 'reason': '', 'machine': machine.name, 'rows': rows, 'runs': runs}


def format_table(result: dict) -> str:
    if result.get('status') != 'ok':
        return f'FTS freeform cuts failed: {result.get("reason")}'
    lines = [f'Ding Ch. 8 freeform cuts (seed {SEED}) on {result["machine"]}, offline at 199.6 kHz, noise on',
             f'{"figure":<44} {"seed":>8} {"ours":>9} {"ratio":>7} {"loop":>9}  unit']
    for r in result['rows']:
        loop = '' if r['predicted'] is None else f'{r["predicted"]:.4g}'
        lines.append(f'{r["name"]:<44} {r["seed"]:>8.4g} {r["ours"]:>9.4g} {r["ratio"]:>7.3f} {loop:>9}  {r["unit"]}'
                     + (f'  > 30 %: {r["note"]}' if r['off'] else ''))
    runs = result['runs']
    lines.append(f'grid at r = 25 mm: fastest component {runs["grid_edge"]["fastest_component_hz"]:.0f} Hz; '
                 f'20 Hz at r = {runs["grid_20hz"]["radius_m"] * 1e3:.2f} mm')
    force = runs['lenslet_force']
    lines.append(f'lenslet force: {force["force_peak_n"]:.3g} N at the full {LENSLET_DEPTH / UM:g} um depth (the '
                 f'calibrated level); the largest deviation {force["deviation_lag_ms"]:.2f} ms after the largest '
                 'force (the thesis: after it, "the 12-degree phase lag at 100 Hz")')
    v, a = runs['beam']['w_peaks']
    lines.append(f'beam integrator: W peaks {v * 1e3:.2f} mm/s, {a:.4g} m/s^2 (limit '
                 f'{runs["beam"]["w_acceleration_limit"]:g} m/s^2: the kinks; run without limits as the thesis did)')
    lines.append('loop: what the continuous loop of the section 5.7 budget predicts for the same plant and gains '
                 '(|T| for p-v and overshoot; |S| x 2 A, both waves at 20 Hz in phase, an upper bound, for the 20 Hz '
                 "following error; the lenslet force's periodic steady state from its harmonics)")
    return '\n'.join(lines)


def plots(result: dict, directory) -> list[str]:
    """fts_freeform.png: the lenslet's force and the deviation it causes over its last periods,
    beside the loop's periodic steady state (Fig. 5-19); the grid's following error where
    its waves are 20 Hz (Ch. 8)."""
    if result.get('status') != 'ok':
        return []
    runs = result['runs']
    period = runs['period']
    plt, fig, (ax, axg) = two_panels(directory)
    force = runs['lenslet_force']
    t = np.arange(len(force['deviation'])) * period * 1e3
    ax.plot(t, force['deviation'] / NM, lw=0.8, label='simulated deviation (with - without force)')
    loop = force['loop']                     # one period from the sine's zero phase (lenslet_steady_state)
    rows = force['plot_first_row'] + np.arange(len(t))
    at = ((rows * period * LENSLET_HZ) % 1.0 * len(loop)).astype(int) % len(loop)
    ax.plot(t, loop[at] / NM, '--', lw=0.8, label='loop: periodic steady state')
    ax.set_xlim(t[0], t[-1])
    ax.set_xlabel('time [ms]')
    ax.set_ylabel('deviation of W [nm]')
    ax.set_title('lenslet, 100 Hz, cutting force (Fig. 5-19)', fontsize=9)
    axf = ax.twinx()
    axf.plot(t, force['force'], color='tab:gray', lw=0.6)
    axf.set_ylabel('force [N]', color='tab:gray')
    ax.legend(fontsize=7, loc='lower left')
    following = runs['grid_20hz']['following']
    axg.plot(np.arange(len(following)) * period * 1e3, following / NM, lw=0.6)
    axg.set_xlabel('time [ms]')
    axg.set_ylabel('following error of W [nm]')
    axg.set_title(f'sinusoidal grid at r = {runs["grid_20hz"]["radius_m"] * 1e3:.2f} mm (20 Hz waves)', fontsize=9)
    return [save_figure(plt, fig, directory, 'fts_freeform.png', wspace=0.36)]   # room for the force axis


def main(argv=None) -> int:
    return print_table(reproduce, format_table)


if __name__ == '__main__':
    raise SystemExit(main())
