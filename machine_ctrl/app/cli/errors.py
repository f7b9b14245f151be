"""The geometric error model (compensation/): ``machine-ctrl fit-errors`` and
``machine-ctrl experiment geometric`` (registered into the experiment group).

* ``fit-errors CSV [--machine M] [--out MODEL] [--json]``: fit quintics (thesis Eqs.
  5.9-5.13) to a measurement CSV (compensation/measurement.py), print the residuals, write
  the model (compensation/error_map.py format) to MODEL.
* ``experiment geometric [MACHINE] [--out DIR] [--json] [--quiet] [--servo-stride K]``: thesis Tables 6.3 and
  6.4 on the simulated machine (machine_ctrl/experiments/compensation.py; Table 6.3 both at
  the commanded joints and through the servo); DIR receives the measurement CSV, the fitted
  model and the PNG plots.

Bad input (CSV, config, model) prints one line ``machine-ctrl: <file>: ...`` and exits 2.
"""
from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

from machine_ctrl.app.cli.common import whole_number
from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
from machine_ctrl.model.errors import ConfigError


def register(subparsers) -> None:
    fit = subparsers.add_parser('fit-errors', help='fit quintic geometric error models to a measurement CSV',
                                description='fit quintic geometric error models to a measurement CSV')
    fit.add_argument('csv')
    fit.add_argument('--machine', default=DEFAULT_MACHINE)
    fit.add_argument('--out', metavar='MODEL', help='write the fitted model (YAML) here')
    fit.add_argument('--json', action='store_true', help='one JSON object on stdout')
    fit.set_defaults(run=cmd_fit_errors, usage_parser=fit)


def register_experiment(experiments) -> None:
    """``experiment geometric`` into the experiment group's subparsers."""
    geometric = experiments.add_parser('geometric', help='thesis Tables 6.3/6.4: geometric error compensation',
                                       description='thesis Tables 6.3/6.4: geometric error compensation')
    geometric.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    geometric.add_argument('--out', metavar='DIR',
                           help='measurement CSV, fitted model and plots (default: a temp dir)')
    geometric.add_argument('--json', action='store_true', help='one JSON object on stdout')
    geometric.add_argument('--quiet', action='store_true', help='no progress on stderr')
    geometric.add_argument('--servo-stride', type=whole_number, default=1, metavar='K',
                           help='Table 6.3 through the servo at every K-th 1 mm position (default 1: all; a quick look)')
    geometric.set_defaults(run=cmd_experiment_geometric, usage_parser=geometric)


def _fail(message: str) -> int:
    print(f'machine-ctrl: {message}', file=sys.stderr)
    return 2


def cmd_fit_errors(args) -> int:
    from compensation.error_map import dump_error_map
    from compensation.fitting import fit_map
    from compensation.measurement import MeasurementError, read_csv
    try:
        machine = load_machine(args.machine)
        model, residuals = fit_map(read_csv(args.csv, machine.axis_names))
    except (ConfigError, MeasurementError) as exc:
        return _fail(str(exc))
    if args.out:
        try:
            Path(args.out).write_text(dump_error_map(model, f'fitted by machine-ctrl fit-errors from {args.csv}'))
        except OSError as exc:
            return _fail(f'{args.out}: cannot write: {exc.strerror}')
    if args.json:
        print(json.dumps({'model': args.out, 'residuals': [r.as_dict() for r in residuals]}))
        return 0
    print(f'{"axis":5} {"error":5} {"points":>6} {"repeats":>7} {"rms residual":>13} {"max residual":>13}'
          f' {"repeatability":>13}')
    for r in residuals:
        scale, unit = (1e6, 'um') if r.error.startswith('d') else (1e6, 'urad')
        print(f'{r.axis:5} {r.error:5} {r.positions:6d} {r.repeats:7d} {r.rms * scale:10.4f} {unit:4}'
              f'{r.max * scale:9.4f} {unit:4}{r.repeatability * scale:9.4f} {unit}')
    return 0


def cmd_experiment_geometric(args) -> int:
    from compensation.error_map import load_error_map
    from compensation.measurement import MeasurementError
    progress = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr, flush=True))
    try:
        machine = load_machine(args.machine)
        path = machine.simulation.error_map_path(machine.yaml_path)
        if path is None:
            return _fail(f'{machine.yaml_path}: simulation.error_map: missing (the experiment needs a true map)')
        true_map = load_error_map(path, machine.axis_names)
        out = Path(args.out or tempfile.mkdtemp(prefix='geometric_'))
        out.mkdir(parents=True, exist_ok=True)
        result = run_experiment(machine, true_map, out, progress, servo_stride=args.servo_stride)
    except (ConfigError, MeasurementError) as exc:
        return _fail(str(exc))
    if args.json:
        print(json.dumps(result))
    else:
        _print(result)
    return 0


def run_experiment(machine, true_map, out: Path, progress, reference=None, servo_stride: int = 1) -> dict:
    """Measure, fit, Table 6.3 (at rest, kinematically, and through the servo at every
    `servo_stride`-th position), Table 6.4 (the planned spiral unless `reference` is given)."""
    from machine_ctrl.experiments import compensation as exp
    from compensation.compensate import Compensator
    from compensation.error_model import ErrorKinematics
    from compensation.fitting import measure_and_fit
    truth = ErrorKinematics.from_config(machine, true_map)
    csv_path, model_path, model, residuals = measure_and_fit(
        truth, true_map, machine.simulation.seed, out, f'{machine.name}, machine-ctrl experiment geometric')
    fitted = Compensator.from_map(machine, model)
    singles = exp.single_axis(machine, truth, fitted, true_map)
    progress('Table 6.3 through the servo: each axis stepped, without and with compensation ...')
    servo, servo_exact = exp.servo_single_axis(machine, true_map, model, servo_stride)
    if reference is None:
        from trajectory.planner import plan
        progress('planning the spiral ...')
        reference = plan('spiral', machine).unwrap().reference
    runs = []
    for label, compensator in (('uncompensated', None), ('compensated', fitted),
                               ('true map', Compensator.from_map(machine, true_map))):
        progress(f'spiral {label}: {len(reference)} steps ...')
        runs.append(exp.spiral_run(machine, truth, fitted.ideal, reference, label, compensator))
    plots = exp.write_plots(out, singles, runs, fitted.fine_axes)
    return {'measurement': str(csv_path), 'model': str(model_path),
            'fit_residuals': [r.as_dict() for r in residuals],
            'table_6_3': exp.table_6_3(singles), 'table_6_3_servo': exp.table_6_3(servo),
            'table_6_3_servo_without_laser_noise': exp.table_6_3(servo_exact),
            'table_6_4': exp.table_6_4(runs),
            'thesis_6_4': exp.THESIS_6_4, 'fine_stroke': exp.fine_stroke_use(machine, runs),
            'plots': [str(p) for p in plots]}


def _print(result: dict) -> None:
    for key, title in (('table_6_3', 'kinematically, the commanded joints'),
                       ('table_6_3_servo', 'through the servo, the laser reading the true tool tip at rest'),
                       ('table_6_3_servo_without_laser_noise', 'through the servo, the laser without its noise')):
        print(f'Table 6.3: tool-tip errors moving one axis, {title}, um (sim | thesis)')
        print(f'{"error":9} {"mean unc.":>18} {"mean comp.":>18} {"max unc.":>18} {"max comp.":>18}')
        for name, row in result[key].items():
            thesis = row['thesis'] or (float('nan'),) * 4
            cells = [f'{row[k]:8.3f} | {t:7.3f}' for k, t in zip(
                ('mean_uncompensated', 'mean_compensated', 'max_uncompensated', 'max_compensated'), thesis)]
            print(f'{name:9} ' + ' '.join(f'{c:>18}' for c in cells))
    print('\nTable 6.4: spiral tool-tip errors |dP|, um: total = tracking + geometric parts')
    for label, row in result['table_6_4'].items():
        for d in 'xyz':
            t, tr, g = (row[k][d] for k in ('total', 'tracking', 'geometric'))
            print(f'{label:14} {d}: mean {t["mean"]:7.3f} max {t["max"]:7.3f}   '
                  f'(tracking mean {tr["mean"]:6.3f} max {tr["max"]:6.3f}; '
                  f'geometric mean {g["mean"]:6.3f} max {g["max"]:6.3f})')
        if row['compensation']:
            print(f'{"":14} compensation: {row["compensation"]}')
    print(f'thesis: {result["thesis_6_4"]} (mean unc., mean comp., max unc., max comp.)')
    print(f'fine stroke used (fraction of half stroke): {result["fine_stroke"]}')
    print('plots: ' + ' '.join(result['plots']))
