"""Sencer Figs. 9-10 on the simulated machines: the Frenet-frame contour-error estimates
(basic, shifted, compensated; Eqs. 20, 22, 26) and the orientation estimate (Eq. 28 and
Eq. 34) against the true contour errors (closest-point search), along the Eq. (35) run of
trt_5axis on the offline runner, and the same estimators on the micromill helix.

Per estimator: the deviation |eps_est - eps_true| (vector difference, um) on average and
at its maximum, over the run's valid steps (rests included) and at the peaks (valid steps
where the true contour error is >= half its maximum); beside it the seed's metric, the
difference of the magnitudes |eps_est| - |eps_true| (Sencer section 4 compares amplitudes:
the shifted frame "does not evaluate the amplitude (|eps|) accurately"), which does not see
an estimate's error in direction. Steps the estimator itself marks
invalid (its bound on |eps_est - eps_true| above the tolerance: machine_ctrl.contour.validity,
README "Contour error" -> "Validity"; the node publishes them as NaN) are excluded from
these statistics, and said so: 'invalid_steps' (by reason), 'max_deviation_invalid_um' (the
largest deviation among them, what the exclusion hides) and 'valid_over_bound' (valid steps
whose deviation exceeds their own bound: 0 if the bound holds). Likewise the orientation
estimate (Eq. 28): its invalid steps are counted and excluded; Eq. (34) has no validity of
its own and no rest rule in the seed (it divides by the rotary velocity), so it is compared
over the steps where the rotary reference moves; the share of those steps where a form
deviates by more than the seed's 6 urad (Sencer Fig. 10) is reported. Orientation in drive coordinates of the rotary
axes (Sencer Fig. 10): true J_O^+ eps (Eq. 36 with the pseudo-inverse) vs Eq. (28) through
J_O^+ (what contour_error_node publishes, in the workpiece frame), vs Eq. (34) as printed
and vs its exact form (G = J_O^T J_O, :func:`machine_ctrl.contour.estimation.rotary_contour_error`). Inputs are the encoder readings, as the node sees them.

``python -m machine_ctrl.experiments.contour [--json] [--plots DIR] [--quiet] [--no-helix]
[--sensitivity [--jobs N]]`` (also ``machine-ctrl experiment contour``); ``--sensitivity``: the
trt run with its assumed friction halved and doubled (:func:`friction_sensitivity`).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from machine_ctrl.model.config import load_machine
from machine_ctrl.contour.estimation import (ESTIMATORS, OrientationEstimator, ToolTipEstimator, ToolTrajectory,
                                  drive_coordinates, rotary_contour_error, rotary_contour_error_eq34)
from machine_ctrl.contour.truth import true_orientation_errors, true_tool_tip_errors
from machine_ctrl.contour.validity import SPEED_TOL
from machine_ctrl.model.kinematics import Kinematics
from hw_sim.offline import run
from machine_ctrl.experiments.tracking import command_use
from trajectory.sencer_path import sencer_reference

UM = 1e6
SEED_ORIENTATION_URAD = 6.0     # Sencer section 4, Figs. 10(c)-(d): Eq. (34)'s deviation "less than 6 urad"


def estimate_run(kinematics: Kinematics, trajectory: ToolTrajectory, measured) -> dict:
    """Tool tips, tool axes, the three tool-tip estimates (+ t_d), the orientation estimate
    and the true errors for measured axis rows (one per step from trajectory.first)."""
    poses = [kinematics.forward(q) for q in measured]
    p = np.array([x[0] for x in poses])
    o = np.array([x[1] for x in poses])
    out = {'p': p, 'o': o, 'true_tip': true_tool_tip_errors(trajectory, p),
           'true_orientation': true_orientation_errors(trajectory, o)}
    for method in ESTIMATORS:
        estimator = ToolTipEstimator(method)
        estimates = [estimator.estimate(trajectory, k, pk) for k, pk in enumerate(p.tolist())]
        out[method] = np.array([e.vector for e in estimates])
        out[f'{method}_delay'] = np.array([e.delay for e in estimates])
        _checks(out, method, estimates)
    orientation = OrientationEstimator()
    estimates = [orientation.update(trajectory, k, ok) for k, ok in enumerate(o.tolist())]
    out['orientation'] = np.array([e.vector for e in estimates])
    _checks(out, 'orientation', estimates)
    return out


def _checks(out: dict, name: str, estimates) -> None:
    """<name>_valid, <name>_bound, <name>_reason per step from the estimates' own checks."""
    out[f'{name}_valid'] = np.array([e.check.valid for e in estimates], dtype=bool)
    out[f'{name}_bound'] = np.array([e.check.bound for e in estimates])
    out[f'{name}_reason'] = np.array([e.check.reason for e in estimates], dtype=object)


def validity_statistics(deviation: np.ndarray, valid: np.ndarray, bound: np.ndarray, reason: np.ndarray,
                        scale: float) -> dict:
    """How many steps were invalid (and why), the largest deviation among them (what the
    exclusion hides) and how many valid steps exceed their own bound; `scale` to um/urad."""
    invalid = ~valid
    reasons, counts = np.unique(reason[invalid].astype(str), return_counts=True)
    return {'invalid_steps': int(invalid.sum()),
            'invalid_by_reason': {str(r): int(c) for r, c in zip(reasons, counts)},
            'max_deviation_invalid': float(deviation[invalid].max() * scale) if invalid.any() else None,
            'valid_over_bound': int((deviation[valid] > bound[valid]).sum())}


def tip_statistics(result: dict) -> dict:
    """Deviation statistics of each estimator over its valid steps only (invalid ones counted,
    not used: validity_statistics)."""
    true = result['true_tip']
    magnitude = np.linalg.norm(true, axis=1)
    peaks = magnitude >= 0.5 * magnitude.max()
    stats = {'true': {'mean_um': magnitude.mean() * UM, 'max_um': magnitude.max() * UM}}
    for method in ESTIMATORS:
        deviation = np.linalg.norm(result[method] - true, axis=1)
        valid = result[f'{method}_valid']
        checks = validity_statistics(deviation, valid, result[f'{method}_bound'], result[f'{method}_reason'], UM)
        used, at_peaks = deviation[valid], deviation[valid & peaks]
        amplitude = np.abs(np.linalg.norm(result[method], axis=1) - magnitude)     # the seed's metric
        stats[method] = {'mean_deviation_um': used.mean() * UM, 'max_deviation_um': used.max() * UM,
                         'peak_max_deviation_um': at_peaks.max() * UM,
                         'peak_max_deviation_percent': 100 * at_peaks.max() / magnitude.max(),
                         'magnitude_mean_deviation_um': amplitude[valid].mean() * UM,
                         'magnitude_max_deviation_um': amplitude[valid].max() * UM,
                         'magnitude_peak_max_deviation_um': amplitude[valid & peaks].max() * UM,
                         'valid_steps': int(valid.sum()), 'invalid_steps': checks['invalid_steps'],
                         'invalid_by_reason': checks['invalid_by_reason'],
                         'max_deviation_invalid_um': checks['max_deviation_invalid'],
                         'valid_over_bound': checks['valid_over_bound']}
    return stats


def rotary_drive_errors(machine, reference, record, result) -> dict:
    """Fig. 10: tracking errors of the rotary axes and the orientation contour errors in
    their coordinates (true, Eq. 28 via J_O^+, Eq. 34 as printed and with G = J_O^T J_O), rad."""
    kinematics = Kinematics.from_config(machine)
    rotary = [i for i, a in enumerate(machine.axes) if a.kind == 'rotary']
    tracking = reference.position[:len(record.measured)] - record.measured
    out = {'tracking': tracking[:, rotary], 'true': [], 'eq28': [], 'eq34': [], 'eq34_exact': []}
    for k, q in enumerate(reference.position[:len(record.measured)]):
        j_o = kinematics.jacobian(q)[3:, rotary]
        out['true'].append(drive_coordinates(j_o, result['true_orientation'][k]))
        out['eq28'].append(drive_coordinates(j_o, result['orientation'][k]))
        out['eq34'].append(rotary_contour_error_eq34(tracking[k, rotary], reference.velocity[k, rotary]))
        out['eq34_exact'].append(rotary_contour_error(tracking[k, rotary], reference.velocity[k, rotary], j_o))
    return {k: np.array(v) for k, v in out.items()}


def experiment(progress=lambda text: None, helix: bool = True) -> tuple[dict, dict]:
    """(summary, series for the plots)."""
    machine = load_machine('trt_5axis')
    kinematics = Kinematics.from_config(machine)
    reference = sencer_reference(machine)
    progress(f'trt_5axis: Eq. (35) run, {len(reference)} steps')
    record = run(machine, reference)
    trajectory = ToolTrajectory.from_reference(kinematics, reference)
    progress('trt_5axis: estimates and true contour errors')
    result = estimate_run(kinematics, trajectory, record.measured)
    drives = rotary_drive_errors(machine, reference, record, result)
    names = [a.name for a in machine.axes if a.kind == 'rotary']
    valid = result['orientation_valid']          # Eq. (28)'s own validity
    rotary = [i for i, a in enumerate(machine.axes) if a.kind == 'rotary']
    velocity = reference.velocity[:len(record.measured)][:, rotary]
    moving = np.linalg.norm(velocity, axis=1) > SPEED_TOL        # Eq. (34) has no rest rule: where the axes move
    used = {'eq28': valid, 'eq34': moving, 'eq34_exact': moving}
    off = {form: np.abs(drives[form][used[form]] - drives['true'][used[form]]) for form in used}
    deviation = np.linalg.norm(result['orientation'] - result['true_orientation'], axis=1)
    summary = {'trt_5axis': {'steps': len(reference), 'fault': record.fault, 'tool_tip': tip_statistics(result),
                             'orientation_max_deviation_urad': {
                                 form: {n: float(off[form][:, i].max() * UM) for i, n in enumerate(names)}
                                 for form in used},
                             'orientation_over_seed_bound_percent': {
                                 form: {n: float(100 * np.mean(off[form][:, i] * UM > SEED_ORIENTATION_URAD))
                                        for i, n in enumerate(names)} for form in used},
                             'orientation_true_max_urad': {n: float(np.abs(drives['true'][:, i]).max() * UM)
                                                           for i, n in enumerate(names)},
                             'orientation_validity': validity_statistics(
                                 deviation, valid, result['orientation_bound'], result['orientation_reason'], UM)}}
    progress('trt_5axis: Eq. (35) run with the cross-coupled contour control')
    summary['trt_5axis']['contour_control'] = coupled_comparison(machine, kinematics, reference, trajectory,
                                                                 record, result)
    series = {'period': machine.control_period, 'result': result, 'drives': drives, 'rotary': names}
    if helix:
        summary['micromill_9axis_helix'] = helix_run(progress)
    return summary, series


def coupled_comparison(machine, kinematics: Kinematics, reference, trajectory: ToolTrajectory, record,
                       result: dict) -> dict:
    """The same run with the machine's cross-coupled contour control on (README "Contour
    control"): mean and max of the true tool-tip (um) and orientation (urad) contour errors,
    uncoupled vs coupled, the largest |command| / command_limit of any axis, and the steps
    whose estimate the coupling could not use (per channel)."""
    coupled = run(machine, reference, contour_control=True)
    poses = [kinematics.forward(q) for q in coupled.measured]
    tip = {'uncoupled': np.linalg.norm(result['true_tip'], axis=1),
           'coupled': np.linalg.norm(true_tool_tip_errors(trajectory, np.array([x[0] for x in poses])), axis=1)}
    axis = {'uncoupled': np.linalg.norm(result['true_orientation'], axis=1),
            'coupled': np.linalg.norm(true_orientation_errors(trajectory, np.array([x[1] for x in poses])), axis=1)}
    def mean_max(errors):
        return {k: {'mean': float(v.mean() * UM), 'max': float(v.max() * UM)} for k, v in errors.items()}
    return {'fault': coupled.fault, 'tool_tip_um': mean_max(tip), 'orientation_urad': mean_max(axis),
            'command_use': {'uncoupled': command_use(machine, record), 'coupled': command_use(machine, coupled)},
            'invalid_steps': coupled.contour_invalid}


# (label, kind of axis, factor on its friction levels): the trt's friction is assumed on every axis
FRICTION_VARIANTS = (('rotary friction x 0.5', 'rotary', 0.5), ('rotary friction x 2', 'rotary', 2.0),
                     ('linear friction x 0.5', 'linear', 0.5), ('linear friction x 2', 'linear', 2.0))


def friction_sensitivity(workers: int | None = None) -> dict:
    """How the Eq. (35) run's figures rest on the assumed friction of trt_5axis (Sencer gives no
    value): the rotary (a, c) and the linear (x, y, z) levels each halved and doubled alone
    (sensitivity.friction_levels). Per variant the true contour errors (tool tip um, orientation
    urad: mean, max) and the compensated estimate's mean and peak deviation (um), and each one's
    ratio to the configured run."""
    from machine_ctrl.experiments import parallel
    jobs = [(None, 1.0)] + [(kind, factor) for _, kind, factor in FRICTION_VARIANTS]
    configured, *varied = parallel.run_all(_friction_run, jobs, workers)
    return {'configured': configured,
            'variants': {label: {**run, 'ratio': {k: run[k] / configured[k] if configured[k] else None for k in run}}
                         for (label, _, _), run in zip(FRICTION_VARIANTS, varied)}}


def _friction_run(kind: str | None, factor: float) -> dict:
    from machine_ctrl.experiments.sensitivity import friction_levels
    machine = load_machine('trt_5axis')
    if kind is not None:
        machine = friction_levels(machine, factor, kind)
    kinematics = Kinematics.from_config(machine)
    reference = sencer_reference(machine)
    record = run(machine, reference)
    if record.fault:
        raise RuntimeError(f'trt_5axis, {kind} friction x {factor:g}: the simulated machine faulted: {record.fault}')
    result = estimate_run(kinematics, ToolTrajectory.from_reference(kinematics, reference), record.measured)
    tip, axis = tip_statistics(result), np.linalg.norm(result['true_orientation'], axis=1) * UM
    return {'tip_mean_um': tip['true']['mean_um'], 'tip_max_um': tip['true']['max_um'],
            'orientation_mean_urad': float(axis.mean()), 'orientation_max_urad': float(axis.max()),
            'compensated_mean_deviation_um': tip['compensated']['mean_deviation_um'],
            'compensated_peak_deviation_um': tip['compensated']['peak_max_deviation_um']}


def friction_table(result: dict) -> str:
    labels = [label for label, _, _ in FRICTION_VARIANTS]
    lines = ['trt_5axis Eq. (35): sensitivity to the assumed friction (ratio to the configured run)',
             f'  {"figure":32s} {"configured":>11s} ' + ' '.join(f'{label:>22s}' for label in labels)]
    for key, value in result['configured'].items():
        ratios = [result['variants'][label]['ratio'][key] for label in labels]
        lines.append(f'  {key:32s} {value:11.4f} ' + ' '.join('n/a'.rjust(22) if r is None else f'{r:22.3f}'
                                                          for r in ratios))
    return '\n'.join(lines)


def helix_run(progress) -> dict:
    """The same estimators on the 9-axis micromill along the [3/7] helix."""
    from trajectory.planner import plan
    machine = load_machine('micromill_9axis')
    progress('micromill_9axis: planning the helix')
    reference = plan('helix', machine).unwrap().reference
    progress(f'micromill_9axis: helix run, {len(reference)} steps')
    record = run(machine, reference, progress=lambda k, n: progress(f'  step {k}/{n}'))
    kinematics = Kinematics.from_config(machine)
    trajectory = ToolTrajectory.from_reference(kinematics, reference)
    progress('micromill_9axis: estimates and true contour errors')
    result = estimate_run(kinematics, trajectory, record.measured)
    deviation = np.linalg.norm(result['orientation'] - result['true_orientation'], axis=1)
    valid = result['orientation_valid']
    return {'steps': len(reference), 'fault': record.fault, 'tool_tip': tip_statistics(result),
            'orientation_max_deviation_urad': float(deviation[valid].max() * UM),
            'orientation_true_max_urad': float(np.linalg.norm(result['true_orientation'], axis=1).max() * UM),
            'orientation_validity': validity_statistics(deviation, valid, result['orientation_bound'],
                                                        result['orientation_reason'], UM)}


def plots(series: dict, directory) -> list[str]:
    """fig9_tool_tip.png and fig10_orientation.png in `directory`."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from pathlib import Path

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    result, drives = series['result'], series['drives']
    t = np.arange(len(result['p'])) * series['period']
    true = np.linalg.norm(result['true_tip'], axis=1) * UM
    fig, ax = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(t, true, 'k', label='true')
    for method in ESTIMATORS:       # invalid steps are gaps (NaN), as the node publishes them
        magnitude = np.where(result[f'{method}_valid'], np.linalg.norm(result[method], axis=1) * UM, np.nan)
        ax[0].plot(t, magnitude, '--', lw=0.8, label=method)
        ax[1].plot(t, magnitude - true, lw=0.8, label=method)
    ax[0].set_ylabel('|contour error| (um)')
    ax[1].set_ylabel('estimate - true (um)')
    ax[1].set_ylim(-0.5, 0.5)
    ax[2].plot(t, result['compensated_delay'] * 1e3)
    ax[2].set_ylabel('t_d, Eq. (21) (ms)')
    ax[2].set_xlabel('time (s)')
    for a in ax[:2]:
        a.legend(loc='upper right')
    fig.suptitle('Sencer Fig. 9 on trt_5axis: tool-tip contour error estimates, Eq. (35) path')
    files = [directory / 'fig9_tool_tip.png']
    fig.savefig(files[0], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(2, len(series['rotary']), figsize=(11, 7), sharex=True)
    for i, name in enumerate(series['rotary']):
        ax[0, i].plot(t, drives['tracking'][:, i] * UM, lw=0.8, label='tracking error')
        ax[0, i].plot(t, drives['true'][:, i] * UM, lw=0.8, label='true contour error')
        ax[0, i].plot(t, drives['eq28'][:, i] * UM, '--', lw=0.8, label='Eq. (28) via J_O+')
        ax[0, i].set_ylabel(f'{name} (urad)')
        ax[1, i].plot(t, (drives['eq28'][:, i] - drives['true'][:, i]) * UM, lw=0.8, label='Eq. (28) - true')
        ax[1, i].plot(t, (drives['eq34'][:, i] - drives['true'][:, i]) * UM, lw=0.8, label='Eq. (34) printed - true')
        ax[1, i].set_ylim(-20, 20)
        ax[1, i].set_xlabel('time (s)')
        for a in ax[:, i]:
            a.legend(loc='upper right', fontsize=7)
    fig.suptitle('Sencer Fig. 10 on trt_5axis: orientation contour errors in drive coordinates')
    files.append(directory / 'fig10_orientation.png')
    fig.savefig(files[1], dpi=110)
    plt.close(fig)
    return [str(f) for f in files]


def table(summary: dict) -> str:
    lines = []
    for run_name, data in summary.items():
        tip = data['tool_tip']
        lines.append(f'{run_name} ({data["steps"]} steps): true contour error mean {tip["true"]["mean_um"]:.3f} um, '
                     f'max {tip["true"]["max_um"]:.3f} um; deviations over each estimator\'s valid steps')
        lines.append(f'  {"estimator":<12} {"mean dev um":>12} {"max dev um":>11} {"peak dev um":>12} {"peak dev %":>11}'
                     f' {"invalid":>8} {"max dev there um":>17} {"over bound":>10} {"||est|-|true|| mean/max/peak um":>32}')
        for method in ESTIMATORS:
            s = tip[method]
            hidden = s['max_deviation_invalid_um']
            lines.append(f'  {method:<12} {s["mean_deviation_um"]:12.4f} {s["max_deviation_um"]:11.3f} '
                         f'{s["peak_max_deviation_um"]:12.4f} {s["peak_max_deviation_percent"]:11.4f} '
                         f'{s["invalid_steps"]:8d} {"-" if hidden is None else f"{hidden:.3f}":>17} '
                         f'{s["valid_over_bound"]:10d} {s["magnitude_mean_deviation_um"]:10.4f} / '
                         f'{s["magnitude_max_deviation_um"]:.4f} / {s["magnitude_peak_max_deviation_um"]:.4f}')
            if s['invalid_steps']:
                lines.append(f'  {"":<12} invalid by reason: {json.dumps(s["invalid_by_reason"])}')
        orientation = data['orientation_max_deviation_urad']
        checks = data['orientation_validity']
        hidden = checks['max_deviation_invalid']
        lines.append(f'  orientation: max deviation from the true contour error (urad): {json.dumps(orientation)}; '
                     f'true max {json.dumps(data["orientation_true_max_urad"])}; Eq. (28) over its valid steps '
                     f'({checks["invalid_steps"]} invalid {json.dumps(checks["invalid_by_reason"])}, max deviation '
                     f'there {"-" if hidden is None else f"{hidden:.3f}"} urad, '
                     f'{checks["valid_over_bound"]} valid over bound)')
        if 'orientation_over_seed_bound_percent' in data:
            lines.append(f'  orientation: Eq. (34) over the steps where the rotary reference moves; share of them '
                         f'deviating more than the seed\'s {SEED_ORIENTATION_URAD:g} urad (%): '
                         f'{json.dumps(data["orientation_over_seed_bound_percent"])}')
        lines.append('  ||est|-|true||: the seed\'s metric, the difference of the magnitudes (blind to direction); '
                     'invalid: steps the estimator marks invalid (bound above tolerance; NaN on the node), '
                     'excluded from the statistics; "max dev there": the largest deviation among them; '
                     '"over bound": valid steps deviating more than their own bound')
        if 'contour_control' in data:
            lines += coupled_table(data['contour_control'])
    return '\n'.join(lines)


def coupled_table(data: dict) -> list[str]:
    """seed | uncoupled | coupled (the seeds have no coupled run: Sencer's Part II is not among them)."""
    lines = ['  cross-coupled contour control (README "Contour control"), true contour errors over the whole run:',
             f'  {"":24s} {"seed":>6s} {"uncoupled":>10s} {"coupled":>10s} {"ratio":>7s}']
    for name, unit, values in (('tool tip', 'um', data['tool_tip_um']), ('orientation', 'urad', data['orientation_urad'])):
        for stat in ('mean', 'max'):
            u, c = values['uncoupled'][stat], values['coupled'][stat]
            lines.append(f'  {f"{stat} {name} ({unit})":24s} {"-":>6s} {u:10.3f} {c:10.3f} {u / c:6.2f}x')
    use = data['command_use']
    lines.append(f'  largest |command| / command_limit of any axis: uncoupled {use["uncoupled"]:.3f}, coupled '
                 f'{use["coupled"]:.3f}; steps without a valid estimate (correction fading): '
                 f'{json.dumps(data["invalid_steps"])}; fault: {data["fault"] or "none"}')
    return lines


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return float(value) if isinstance(value, (np.floating, float)) else value


def _whole_number(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'a whole number > 0, got {text}')
    return value


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='machine-ctrl experiment contour', description=__doc__.split('\n')[0])
    parser.add_argument('--json', action='store_true', help='print one JSON object')
    parser.add_argument('--plots', metavar='DIR', help='write fig9_tool_tip.png and fig10_orientation.png')
    parser.add_argument('--quiet', action='store_true', help='no progress on stderr')
    parser.add_argument('--no-helix', action='store_true', help='skip the micromill helix run')
    parser.add_argument('--sensitivity', action='store_true',
                        help="only the trt run's sensitivity to its assumed friction (rotary, linear; halved, doubled)")
    parser.add_argument('--jobs', type=_whole_number, metavar='N', help='--sensitivity: runs in up to N processes')
    return command(parser.parse_args(argv))


def command(args) -> int:
    """The command on parsed arguments (main's; also `machine-ctrl experiment contour`)."""
    progress = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    if args.sensitivity and args.plots:
        print('machine-ctrl experiment contour: --plots is for the figures\' run, not with --sensitivity', file=sys.stderr)
        return 2
    if args.sensitivity:
        progress(f'trt_5axis: Eq. (35) runs, friction as configured and {len(FRICTION_VARIANTS)} variants')
        result = friction_sensitivity(args.jobs)
        print(json.dumps(_jsonable(result)) if args.json else friction_table(result))
        return 0
    summary, series = experiment(progress, helix=not args.no_helix)
    if args.plots:
        for path in plots(series, args.plots):
            progress(f'wrote {path}')
    print(json.dumps(_jsonable(summary)) if args.json else table(summary))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
