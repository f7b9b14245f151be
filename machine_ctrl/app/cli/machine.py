"""``machine-ctrl info`` and ``machine-ctrl fk``: the machine model (config, kinematics).

* ``info [MACHINE] [--json]``: the machine. Text is a table for people; ``--json`` prints
  one object: name, description, control_period (s), axes (in axis order: name, kind, unit,
  drive, stroke [lo, hi] or null when unlimited, velocity, acceleration, jerk,
  sensor_resolution, command_limit) and home (q, tool_tip [m], tool_axis).
* ``fk [MACHINE]``: one configuration per line from stdin (whitespace separated, axis order
  of ``info``, SI units; blank lines and ``#`` lines skipped) -> ``Px Py Pz Oi Oj Ok`` per
  configuration (tool tip in m and unit tool axis, workpiece frame; shortest round-trip
  float text). A malformed line prints ``line N: problem`` on stderr, the next line is read
  and the exit status is then 1. Positions outside the strokes are evaluated all the same.
"""
from __future__ import annotations

import json
import math
import sys

from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine


def register(subparsers) -> None:
    info = subparsers.add_parser('info', help='print the machine: axes, strokes, limits, drives, home pose')
    info.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    info.add_argument('--json', action='store_true', help='one JSON object on stdout')
    info.set_defaults(run=cmd_info)
    fk = subparsers.add_parser('fk', help='forward kinematics of configurations read from stdin')
    fk.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    fk.set_defaults(run=cmd_fk)


def _fmt(values) -> str:
    return ' '.join(repr(float(v)) for v in values)


def machine_summary(machine, kinematics) -> dict:
    tip, axis = kinematics.forward(machine.home)
    return {
        'name': machine.name,
        'description': machine.description,
        'control_period': machine.control_period,
        'axes': [{
            'name': a.name,
            'kind': a.kind,
            'unit': a.unit,
            'drive': a.drive.type,
            'stroke': list(a.stroke) if a.stroke else None,
            'velocity': a.limits.velocity,
            'acceleration': a.limits.acceleration,
            'jerk': a.limits.jerk,
            'sensor_resolution': a.sensor_resolution,
            'command_limit': a.drive.command_limit,
        } for a in machine.axes],
        'home': {'q': list(machine.home), 'tool_tip': tip.tolist(), 'tool_axis': axis.tolist()},
    }


def _print_info(summary: dict) -> None:
    print(f"machine  {summary['name']}: {summary['description']}")
    period = summary['control_period']
    print(f'control  period {period:g} s ({1 / period:g} Hz)')
    rows = [('axis', 'unit', 'drive', 'stroke_min', 'stroke_max', 'v_max/s', 'a_max/s^2', 'j_max/s^3')]
    for a in summary['axes']:
        stroke = [f'{v:g}' for v in a['stroke']] if a['stroke'] else ['unlimited', 'unlimited']
        rows.append((a['name'], a['unit'], a['drive'], *stroke,
                     *(f"{a[k]:g}" for k in ('velocity', 'acceleration', 'jerk'))))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print('  '.join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    home = summary['home']
    print(f"home q          {_fmt(home['q'])}")
    print(f"home tool tip   {_fmt(home['tool_tip'])}  (m, workpiece frame)")
    print(f"home tool axis  {_fmt(home['tool_axis'])}")


def cmd_info(args) -> int:
    from machine_ctrl.model.kinematics import Kinematics
    machine = load_machine(args.machine)
    summary = machine_summary(machine, Kinematics.from_config(machine))
    if args.json:
        print(json.dumps(summary))
    else:
        _print_info(summary)
    return 0


def parse_configuration(line: str, n: int) -> list[float]:
    """Axis positions from one whitespace-separated line; ValueError names the problem."""
    fields = line.split()
    if len(fields) != n:
        raise ValueError(f'expected {n} values, got {len(fields)}')
    values = []
    for i, text in enumerate(fields, 1):
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f'value {i} ({text!r}) is not a number') from None
        if not math.isfinite(value):
            raise ValueError(f'value {i} ({text!r}) is not finite')
        values.append(value)
    return values


def cmd_fk(args) -> int:
    from machine_ctrl.model.kinematics import Kinematics
    machine = load_machine(args.machine)
    kinematics = Kinematics.from_config(machine)
    status = 0
    for number, line in enumerate(sys.stdin, 1):
        if not line.strip() or line.lstrip().startswith('#'):
            continue
        try:
            q = parse_configuration(line, len(machine.axes))
        except ValueError as exc:
            print(f'line {number}: {exc} (axes: {" ".join(machine.axis_names)})', file=sys.stderr,
                  flush=True)
            status = 1
            continue
        p, o = kinematics.forward(q)
        print(_fmt((*p, *o)), flush=True)
    return status
