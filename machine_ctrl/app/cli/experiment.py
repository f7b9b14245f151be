"""``machine-ctrl experiment NAME ...``: the experiments on the simulated machine (offline
runner, machine_ctrl.experiments and compensation/), one subcommand each; progress on stderr.

* ``midrange [--json] [--plots DIR]`` (Sörnmo Table 3.1), ``piezo-milling [--json] [--plots DIR]`` (Sörnmo
  Tables 2.1/2.2), ``deflection [--json] [--plots DIR]`` (Sörnmo Table 4.1), ``feed-force [--json]
  [--plots DIR]`` (Sörnmo Ch. 5), ``fts-budget [--json]
  [--plots DIR]`` (Ding section 5.7), ``fts-freeform [--json] [--plots DIR]`` (Ding Ch. 8 on fts_lathe),
  ``fts-h2``, ``fts-accel`` [--json] [--plots DIR] (Ding Ch. 6/7), ``fts-flexure [--json]`` (Ding 6.5.2) and
  ``fts-identify [--json]`` (Ding section 5.5): machine_ctrl.experiments.midrange / piezo_milling /
  deflection / feed_force / fts_budget / fts_freeform / fts_h2 / fts_accel / fts_flexure / fts_identify, seed | ours | ratio (feed-force: the seed
  prints no table, its figures' statements beside our measurements).
* ``circle|square|frf [MACHINE] [--json] [--quiet] [--record DIR] [--steps N] [--sensitivity]
  [--identified FILE]... [--jobs N]``: thesis section 6.3 /
  Fig. 4.10. ``--json``: circle/square print ``{"smc": {...}, "dsfd": {...}, "measured":
  {...}, "true": {...}, "at_rest": {...}, "noise_floor": {...}, "command_use": {...},
  "encoder_count_um": ..., "steps": ..., "identified": ..., "notes": [...]}`` (and "ccc" where
  the machine has contour control); "smc"/"dsfd" hold mean_x_tracking, mean_y_tracking,
  mean_contour, max_x_tracking, max_y_tracking, max_contour in um, null where the figure is
  the noise floor (no larger than at rest: tracking.noise_floor), which the table prints as
  "floor"; "measured" has every encoder figure, "true" the same against the simulator's
  true positions; frf prints ``{"bandwidth_hz": {"x_c": ..., "x_f": ..., "x_dual": ...,
  ...}, "crossover_hz": {...}, "design_hz": {...}, "frequencies_hz": [...], "gain": {...},
  "identified": ...}``. circle/square ``--record DIR`` also
  write each run as a bag, DIR/smc and DIR/dsfd, and their at-rest twins DIR/smc_at_rest and
  DIR/dsfd_at_rest (machine_ctrl.ros.run_bag, called here: the experiments layer is ROS-free).
  circle/square ``--steps N``: only the first N control steps of each run (a quick look).
  On a machine with a ``contour_control`` section circle/square also run the dual stage with
  the cross-coupled contour control ("ccc", and its at-rest twin) and print thesis | DSFD |
  CCC.
* ``contour [--json] [--plots DIR] [--quiet] [--no-helix] [--sensitivity [--jobs N]]``: Sencer Figs. 9-10
  (machine_ctrl.experiments.contour), and the Eq. (35) run uncoupled vs with the
  cross-coupled contour control.
* ``geometric [MACHINE] [--out DIR] [--json] [--quiet] [--servo-stride K]``: thesis Tables 6.3/6.4, registered
  by the error-model group (errors.py).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from machine_ctrl.app.cli import errors
from machine_ctrl.app.cli.common import error, fresh_directory, whole_number
from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine

EXPERIMENT_TITLES = {
    'circle': 'Circle R = 30 mm at 600 mm/min on x-y (thesis Table 6.1)',
    'square': 'Square, side 20 mm (assumed), 600 mm/min on x-y (thesis Table 6.2)',
}
STAT_LABELS = ('Mean x-axis tracking', 'Mean y-axis tracking', 'Mean contour',
               'Max x-axis tracking', 'Max y-axis tracking', 'Max contour')
# the first line of machine_ctrl.experiments.contour's docstring (not imported: numpy, Pinocchio)
CONTOUR_DESCRIPTION = ('Sencer Figs. 9-10 on the simulated machines: the Frenet-frame contour-error '
                       'estimates')


# the seed-table experiments: subcommand, module of machine_ctrl.experiments, its entry point,
# help, and the help of --plots DIR where the module writes plots (module.plots)
SEED_TABLES = (
    ('midrange', 'midrange', 'table_3_1',
     'Sörnmo Table 3.1: adaptive mid-ranging (AIMC) vs MVPC, the simulation rows with their spread',
     'write midrange.png: the AIMC on the r_r = 5 reference (Fig. 3.6) and the gain estimate through the steps of '
     'Fig. 3.7'),
    ('piezo-milling', 'piezo_milling', 'reproduce',
     "Sörnmo Ch. 2, Tables 2.1/2.2: the piezo micro manipulator's axes identified from chirps, their LQG at 10 kHz "
     "following the robot's deviation in milling, with vs without compensation",
     'write piezo_milling.png: the profile errors along the cut and their spectra (Figs. 2.19-2.21)'),
    ('deflection', 'deflection', 'reproduce',
     "Sörnmo Ch. 4, Table 4.1: the robot's deflection in face milling compensated by force or position feedback",
     'write deflection_table_4_1.png: the position errors, the force and the corrections (Figs. 4.6-4.7)'),
    ('feed-force', 'feed_force', 'reproduce',
     "Sörnmo Ch. 5: adaptive feed-rate force control in robotic milling (Figs. 5.4, 5.6, 5.7), adaptive vs D_f fixed",
     'write feed_force.png: the force of both controllers, D_f with its estimate and the feed'),
    ('fts-budget', 'fts_budget', 'reproduce',
     "Ding section 5.7: the fast tool servo's error budget (following vs real positioning error)",
     'write the PSD/CAS and bandwidth-sweep PNGs (the spectra are not in --json)'),
    ('fts-freeform', 'fts_freeform', 'reproduce',
     'Ding Ch. 8: spindle-slaved freeform cuts on fts_lathe (grid, lenslet, beam integrator), offline at 199.6 kHz',
     "write fts_freeform.png: the lenslet's force and W's deviation beside the loop (Fig. 5-19), the 20 Hz grid's "
     'following error'),
    ('fts-h2', 'fts_h2', 'reproduce',
     "Ding Ch. 6: the H2-optimal law against the PID on fts_lathe's W at 20 kHz, offline with all noise",
     'write fts_h2.png: |y/r| of both laws and their following-error spectra (Fig. 6-12)'),
    ('fts-accel', 'fts_accel', 'reproduce',
     "Ding Ch. 7: acceleration feedback on fts_lathe's W, dynamic compliance and the intermittent cut, offline",
     'write fts_accel.png: dynamic compliance (Figs. 7-13, 7-14) and the cut (Fig. 7-17)'),
    ('fts-flexure', 'fts_flexure', 'reproduce',
     "Ding section 6.5.2, Fig. 6-17: W's following error under the H2 law over flexure stiffness and damping", None),
    ('fts-identify', 'fts_identify', 'reproduce',
     "Ding section 5.5: Table 5-2 from a stepped-sine FRF of fts_lathe's W stage by a grey-box fit", None),
)


def register(subparsers) -> None:
    experiment = subparsers.add_parser('experiment', help='thesis experiments on the simulated machine',
                                       description='experiments on the simulated machine (offline runner)')
    names = experiment.add_subparsers(dest='name', required=True)
    for name, help_text in (('circle', 'thesis Table 6.1: circle, sliding mode vs dual stage'),
                            ('square', 'thesis Table 6.2: square, sliding mode vs dual stage'),
                            ('frf', 'thesis Fig. 4.10: closed-loop frequency responses')):
        parser = names.add_parser(name, help=help_text)
        parser.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
        parser.add_argument('--json', action='store_true', help='one JSON object on stdout')
        parser.add_argument('--quiet', action='store_true', help='no progress on stderr')
        parser.add_argument('--record', metavar='DIR',
                            help=('also write each run as a bag, DIR/smc and DIR/dsfd' if name != 'frf'
                                  else argparse.SUPPRESS))     # frf: refused with one line, as before
        parser.add_argument('--sensitivity', action='store_true',
                            help=('also run the machine with its bristle stiffness and its table force noise halved '
                                  'and doubled, and print each statistic\'s ratio to the configured run'
                                  if name != 'frf' else argparse.SUPPRESS))
        parser.add_argument('--identified', metavar='FILE', action='append', default=[],
                            help="the controllers' values from FILE (machine-ctrl identify --out) over the "
                                 "machine's own; hw_sim's plant stays the truth (repeat for several axes)")
        parser.add_argument('--jobs', type=whole_number, metavar='N',
                            help='run the independent simulations in up to N processes (default: the '
                                 'available CPUs; the same numbers whatever N)')
        parser.add_argument('--steps', type=whole_number, metavar='N',
                            help=('run only the first N control steps of the contour (and of its at-rest '
                                  'twins): a quick look; the table then describes that part only'
                                  if name != 'frf' else argparse.SUPPRESS))
        parser.set_defaults(run=cmd_experiment)
    contour = names.add_parser('contour', help='Sencer Figs. 9-10: contour-error estimates vs true errors',
                               description=CONTOUR_DESCRIPTION)
    contour.add_argument('--json', action='store_true', help='print one JSON object')
    contour.add_argument('--plots', metavar='DIR', help='write fig9_tool_tip.png and fig10_orientation.png')
    contour.add_argument('--quiet', action='store_true', help='no progress on stderr')
    contour.add_argument('--no-helix', action='store_true', help='skip the micromill helix run')
    contour.add_argument('--sensitivity', action='store_true',
                         help="only the trt run's sensitivity to its assumed friction (rotary, linear; halved, doubled)")
    contour.add_argument('--jobs', type=whole_number, metavar='N', help='--sensitivity: runs in up to N processes')
    contour.set_defaults(run=cmd_contour, usage_parser=contour)
    for name, module, entry, help_text, plots in SEED_TABLES:
        parser = names.add_parser(name, help=help_text)
        parser.add_argument('--json', action='store_true', help='one JSON object on stdout')
        if plots:
            parser.add_argument('--plots', metavar='DIR', help=plots)
        parser.set_defaults(run=cmd_seed_table, module=module, entry=entry)
    errors.register_experiment(names)


def _progress(label: str, done: int, total: int) -> None:
    print(f'\r{label}: {100 * done // max(total, 1):3d} %', end='' if done < total else '\n',
          file=sys.stderr, flush=True)


FLOOR = 'floor'     # printed instead of a figure that is the noise floor (tracking.noise_floor)


def contouring_notes(result: dict) -> list[str]:
    """What the table's cells are, and which are not results, in words (table and JSON)."""
    from machine_ctrl.experiments.tracking import STAT_KEYS
    count = result['encoder_count_um']
    notes = ['errors from the encoders, x = x_c + x_f and y = y_c + y_f, as the thesis measured them; '
             '"true": the same errors against the simulator\'s true positions (in parentheses where the '
             'encoder figure is the floor)',
             '"at rest": the same statistics with the machine holding the start point for as long '
             '(same mode, same simulated noise: hw_sim is seeded)']
    for mode in result['noise_floor']:
        floor = result['noise_floor'][mode]
        if not floor:
            continue
        labels = ', '.join(f'{STAT_LABELS[STAT_KEYS.index(k)].lower()} {result[mode][k]:.3f} '
                           f'(at rest {result["at_rest"][mode][k]:.3f})' for k in floor)
        notes.append(f'{FLOOR} ({mode.upper()}): {labels} um: no larger than at rest (maxima within one '
                     f'{count * 1000:.0f} nm encoder count): the simulated table\'s own force-noise excursion '
                     f'(plant.force_noise, assumed), not a contouring result; not compared with the thesis')
    return notes


def contouring_json(result: dict) -> dict:
    """The --json object: 'smc'/'dsfd' (and 'ccc', the dual stage with the cross-coupled
    contour control, where the machine has one) hold the results, null where the cell is the
    noise floor; 'measured' every encoder figure; 'true', 'at_rest', 'noise_floor',
    'command_use' (largest |command| / command_limit of any axis), 'encoder_count_um',
    'steps', 'notes' (and, from cmd_experiment, 'identified': the belief files used, absolute)."""
    modes = tuple(result['noise_floor'])
    out = {mode: {k: (None if k in result['noise_floor'][mode] else v) for k, v in result[mode].items()}
           for mode in modes}
    out['measured'] = {mode: result[mode] for mode in modes}
    for key in ('true', 'at_rest', 'noise_floor', 'command_use', 'encoder_count_um', 'steps'):
        out[key] = result[key]
    out['notes'] = contouring_notes(result)
    return out


def _print_contouring(kind: str, machine: str, result: dict) -> None:
    from machine_ctrl.experiments.tracking import STAT_KEYS, THESIS
    floor = result['noise_floor']

    def cell(mode, key):
        return f'{FLOOR:>9s}' if key in floor[mode] else f'{result[mode][key]:9.3f}'

    def true_cell(mode, key):     # in parentheses: the truth of a floor cell, not a result either
        value = result['true'][mode][key]
        return f'{f"({value:.3f})":>9s}' if key in floor[mode] else f'{value:9.3f}'

    print(f'{EXPERIMENT_TITLES[kind]}; {machine} simulation; errors in um')
    print(f'{"":22s} {"SMC sim":>9s} {"at rest":>9s} {"thesis":>9s} {"DSFD sim":>9s} {"at rest":>9s} {"thesis":>9s}'
          f' {"true SMC":>9s} {"true DSFD":>9s}')
    for key, label in zip(STAT_KEYS, STAT_LABELS):
        i = STAT_KEYS.index(key)
        print(f'{label:22s} {cell("smc", key)} {result["at_rest"]["smc"][key]:9.3f} {THESIS[kind]["smc"][i]:9.3f} '
              f'{cell("dsfd", key)} {result["at_rest"]["dsfd"][key]:9.3f} {THESIS[kind]["dsfd"][i]:9.3f} '
              f'{true_cell("smc", key)} {true_cell("dsfd", key)}')
    for key, label in (('max_contour', 'max contour'), ('max_y_tracking', 'max y tracking')):
        i = STAT_KEYS.index(key)
        theirs = THESIS[kind]['smc'][i] / THESIS[kind]['dsfd'][i]
        at_floor = [m.upper() for m in ('smc', 'dsfd') if key in floor[m]]
        if at_floor:
            print(f'SMC/DSFD {label}: n/a, {" and ".join(at_floor)} at the noise floor (thesis {theirs:.2f}x)')
        else:
            print(f'SMC/DSFD {label}: {result["smc"][key] / result["dsfd"][key]:.2f}x (thesis {theirs:.2f}x)')
    if 'ccc' in result:
        _print_coupled(kind, result, cell)
    for note in contouring_notes(result):
        print(f'* {note}')


def _print_coupled(kind: str, result: dict, cell) -> None:
    """seed | uncoupled | coupled: the dual stage without and with the cross-coupled contour
    control (README "Contour control"); the thesis has no coupled run."""
    from machine_ctrl.experiments.tracking import STAT_KEYS, THESIS
    print('Cross-coupled contour control on the dual stage (DSFD + CCC); errors in um; the ratio is n/a where '
          'a cell is the noise floor')
    print(f'{"":22s} {"thesis":>9s} {"DSFD sim":>9s} {"CCC sim":>9s} {"at rest":>9s} {"true CCC":>9s}'
          f' {"DSFD/CCC":>9s}')
    for key, label in zip(STAT_KEYS, STAT_LABELS):
        floor = key in result['noise_floor']['dsfd'] or key in result['noise_floor']['ccc']
        ratio = 'n/a' if floor else f'{result["dsfd"][key] / result["ccc"][key]:.2f}x'
        print(f'{label:22s} {THESIS[kind]["dsfd"][STAT_KEYS.index(key)]:9.3f} {cell("dsfd", key)} '
              f'{cell("ccc", key)} {result["at_rest"]["ccc"][key]:9.3f} {result["true"]["ccc"][key]:9.3f} '
              f'{ratio:>9s}')
    print('largest |command| / command_limit of any axis: '
          + ', '.join(f'{m.upper()} {result["command_use"][m]:.3f}' for m in result['command_use']))


def _print_frf(machine: str, result: dict) -> None:
    names = list(result['gain'])
    print(f'Closed-loop frequency responses, servo loop alone (thesis Fig. 4.10); {machine} simulation')
    print('   f/Hz ' + ' '.join(f'{n:>8s}' for n in names) + '   (gain, dB)')
    for i, f in enumerate(result['frequencies_hz']):
        print(f'{f:7.1f} ' + ' '.join(f'{20 * math.log10(max(result["gain"][n][i], 1e-12)):8.2f}' for n in names))
    print('-3 dB bandwidth/Hz ' + ' '.join(
        f'{n}={"n/a" if b is None else f"{b:.1f}"}' for n, b in result['bandwidth_hz'].items()))
    if result['crossover_hz']:
        print('open-loop crossover/Hz (L = T/(1 - T), laws on the error alone) ' + ' '.join(
            f'{n}={"n/a" if c is None else f"{c:.1f}"}' for n, c in result['crossover_hz'].items()))
    if result['design_hz']:
        print('design bandwidth/Hz (the laws\' own: the thesis\'s numbers) ' + ' '.join(
            f'{n}={d:.1f}' for n, d in result['design_hz'].items()))


def contouring(machine, kind: str, progress=None, steps: int | None = None, record_dir=None,
               workers: int | None = None, coupled: bool = False) -> dict:
    """machine_ctrl.experiments.tracking.contouring; with `record_dir`, each run is also
    written as a bag, <record_dir>/<label> (tracking.run_labels), right after it ran."""
    from machine_ctrl.experiments import tracking
    def write_bag(label, reference, record):
        from machine_ctrl.ros.run_bag import write_run_bag     # imports rclpy: only when recording
        write_run_bag(Path(record_dir) / label, machine, reference, record, f'experiment {kind} {label}')
    return tracking.contouring(machine, kind, progress=progress, steps=steps,
                               on_run=None if record_dir is None else write_bag, workers=workers, coupled=coupled)


def cmd_experiment(args) -> int:
    machine = load_machine(args.machine, belief=args.identified)
    if args.identified and not args.quiet:
        print(f"the controllers' values from {', '.join(args.identified)}", file=sys.stderr)
    progress = None if args.quiet else _progress
    coupled = machine.contour_control is not None      # circle/square: also the dual stage with it
    if args.sensitivity and args.record is not None:
        return error('experiment', '--record is for one run, not with --sensitivity')
    if args.record is not None:
        try:
            if args.name == 'frf':
                raise ValueError('--record is for circle and square')
            from machine_ctrl.experiments.tracking import run_labels
            for label in run_labels(coupled):
                fresh_directory(os.path.join(args.record, label))
        except ValueError as exc:
            return error('experiment', exc)
    if args.name == 'frf' and (args.steps is not None or args.sensitivity):
        return error('experiment', f'{"--steps" if args.steps is not None else "--sensitivity"} is for circle and square')
    belief = {'identified': [str(Path(f).resolve()) for f in args.identified]}   # as the servos' belief parameter
    if args.sensitivity:
        from machine_ctrl.experiments import sensitivity
        result = sensitivity.sensitivity(machine, args.name, steps=args.steps, workers=args.jobs, progress=progress)
        print(json.dumps({'configured': {m: result['configured'][m] for m in ('smc', 'dsfd')},
                          'variants': result['variants'], **belief}) if args.json
              else sensitivity.table(args.name, result))
        return 0
    if args.name == 'frf':
        from machine_ctrl.experiments import tracking
        result = tracking.frf(machine, progress=progress, workers=args.jobs)
        if args.json:
            print(json.dumps({**{key: result[key] for key in ('bandwidth_hz', 'crossover_hz', 'design_hz',
                                                               'frequencies_hz', 'gain')}, **belief}))
        else:
            _print_frf(machine.name, result)
        return 0
    result = contouring(machine, args.name, progress=progress, steps=args.steps, record_dir=args.record,
                        workers=args.jobs, coupled=coupled)
    if args.json:
        print(json.dumps({**contouring_json(result), **belief}))
    else:
        _print_contouring(args.name, machine.name, result)
    return 0


def cmd_contour(args) -> int:
    from machine_ctrl.experiments import contour
    return contour.command(args)


def _scalars(value):
    """A result as JSON data: numbers, text, lists and mappings (dataclasses as their fields);
    arrays (spectra) left out."""
    import dataclasses

    import numpy as np
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _scalars(dataclasses.asdict(value))
    if isinstance(value, dict):
        return {str(k): _scalars(v) for k, v in value.items() if not isinstance(v, np.ndarray)}
    if isinstance(value, (list, tuple)):
        return [_scalars(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def cmd_seed_table(args) -> int:
    """midrange (machine_ctrl.experiments.midrange.table_3_1), piezo-milling, deflection,
    feed-force and the fts-* experiments (their reproduce()): the table seed | ours | ratio,
    or --json; exit 1 when the experiment reports a failure (its reason on stderr)."""
    import importlib
    module = importlib.import_module(f'machine_ctrl.experiments.{args.module}')
    result = getattr(module, args.entry)()
    if args.json:
        print(json.dumps(_scalars(result)))
    else:
        print(module.format_table(result))
    for path in (module.plots(result, args.plots) if getattr(args, 'plots', None) else []):
        print(f'wrote {path}', file=sys.stderr)
    if result['status'] != 'ok':       # the experiment ran and failed: 1, as a refused goal (2: bad arguments)
        error(f'experiment {args.name}', result['reason'])
        return 1
    return 0
