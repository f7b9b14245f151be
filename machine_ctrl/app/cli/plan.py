"""``machine-ctrl plan PATH --machine M --out DIR [--json] [--feed F]``: plan a tool path
(CSV or built-in name; trajectory.planner) or a G-code part program (``.ngc``, ``.nc``,
``.gcode``, ``.tap``; trajectory.part_program: its F words are the feeds) without running
it, write DIR/references.csv (``time,<axes>``, SI: time, then each axis position in info
order) and print traversal time, planning time, max tool-pose deviation and per-axis peak
|v|, |a|, |j| over the limits, for a program also each piece and what was ignored
(``--json``: one object)."""
from __future__ import annotations

import json
import os
import sys

from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine


def register(subparsers) -> None:
    plan = subparsers.add_parser('plan', help='plan a toolpath and write the sampled references')
    plan.add_argument('path', help='CSV file (px,py,pz,oi,oj,ok, SI), built-in toolpath name or G-code program '
                      '(.ngc .nc .gcode .tap)')
    plan.add_argument('--machine', default=DEFAULT_MACHINE)
    plan.add_argument('--out', required=True, help='directory for references.csv')
    plan.add_argument('--json', action='store_true', help='one JSON object on stdout')
    plan.add_argument('--feed', type=float, help='process feed limit, m/s (default: the planner\'s, 10 mm/s)')
    plan.set_defaults(run=cmd_plan)


def write_references(directory: str, reference, axis_names) -> None:
    """DIR/references.csv: ``time,<axes>`` header, then one row per sample (SI)."""
    import numpy as np
    os.makedirs(directory, exist_ok=True)
    table = np.column_stack((np.arange(len(reference)) * reference.period, reference.position))
    np.savetxt(os.path.join(directory, 'references.csv'), table, fmt='%.17g', delimiter=',',
               header='time,' + ','.join(axis_names), comments='')


def cmd_plan(args) -> int:
    from trajectory import part_program
    from trajectory.planner import DEFAULT_FEED, plan
    machine = load_machine(args.machine)
    program = part_program.is_program(args.path)
    if program and args.feed is not None:
        print('machine-ctrl: plan: --feed does not apply to a G-code program (its F words are the feeds)',
              file=sys.stderr)
        return 2
    try:
        if program:
            result = part_program.plan_program(args.path, machine)
            reference = result.reference() if result.ok else None
        else:
            result = plan(args.path, machine, feed=DEFAULT_FEED if args.feed is None else args.feed)
            reference = result.plan.reference if result.ok else None
        if result.ok:
            write_references(args.out, reference, machine.axis_names)
    except OSError as exc:
        print(f'machine-ctrl: plan: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    if not result.ok:
        print(f'machine-ctrl: plan: {" ".join(result.reason.split())}', file=sys.stderr)
        return 2
    summary = result.summary() if program else result.plan.summary()
    if args.json:
        print(json.dumps(summary))
        return 0
    if program:
        print(f"pieces           {len(summary['pieces'])} (an exact stop between pieces)")
        for n, (piece, planned) in enumerate(zip(result.pieces, result.plans), start=1):
            print(f"  {n:3d}  {piece.where:>11s}  {piece.label:>20s}  {planned.traversal_time:.4f} s"
                  f"{'  M0 stop after' if piece.stop_after else ''}")
        for note in summary['notes']:
            print(f'note: {note}')
    print(f"traversal time   {summary['traversal_time']:.4f} s ({summary['samples']} samples)")
    print(f"planning time    {summary['planning_time']:.3f} s")
    print(f"max deviation    {summary['max_position_deviation']:.3g} m, "
          f"{summary['max_orientation_deviation']:.3g} rad")
    print(f"tool feed        {summary['peak_feed_ratio']:.4f} of the feed limit at its peak")
    print('axis  |v|/v_max  |a|/a_max  |j|/j_max')
    for name, r in summary['peak_ratios'].items():
        print(f"{name:5s} {r['velocity']:9.4f}  {r['acceleration']:9.4f}  {r['jerk']:9.4f}")
    return 0
