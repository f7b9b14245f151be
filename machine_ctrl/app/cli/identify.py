"""``machine-ctrl identify AXIS [--machine M] [--out FILE] [--json] [--jobs N]``: identify an
axis offline on hw_sim by the method its drive calls for (machine_ctrl.experiments.identify.
identify_axis): a feed drive's rigid body, friction curve, friction along the stroke and
disturbance observer; a flexure stage's grey-box model from its frequency response; a piezo
stage's N4SID model. The table prints seed | true | identified | error; the
identified values as a machine-YAML fragment go to FILE with ``--out``; ``--json`` prints
the result as one object, {"status", "reason", "axis", "method", ...}: for a feed drive
"rigid_body", "steady", "bristles", "observer" ({"identified", "true"}), "frf" (the closed
loop's frequency response with coherence), "true", "seed", "speeds", "forces"; for the other methods "rows" ([parameter, seed, true, identified]) and
"notes", for a flexure stage "model" ({"m12", "c2", "k2", "m4", "c4", "k4", "rms_log_residual"}: what ``--out``
writes, the model of its H2 law), for a piezo stage "model" ({"modes": [{"omega", "zeta"}], "real_pole", "order",
"vaf"}: what ``--out`` writes) (SI: m/s, N, the observer gains per m and m/s; the fits' dataclasses as mappings). Progress on stderr; exit 1 when the identification is refused
(the reason on stderr).
"""
from __future__ import annotations

import json
import sys

from machine_ctrl.app.cli.common import error
from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine


def register(subparsers) -> None:
    parser = subparsers.add_parser('identify', help="identify an axis by its drive's method (offline, on hw_sim)",
                                   description=__doc__.split('\n\n')[0].replace('``', ''))
    parser.add_argument('axis', help='a feed drive with guideway friction (x_c), a flexure stage (fts_lathe w) or a '
                                     'piezo stage (robot_piezo px)')
    parser.add_argument('--machine', default=DEFAULT_MACHINE, help=f'machine name or YAML (default {DEFAULT_MACHINE})')
    parser.add_argument('--out', metavar='FILE', help='write the identified values as a machine-YAML fragment')
    parser.add_argument('--json', action='store_true', help='one JSON object on stdout')
    parser.add_argument('--jobs', type=int, metavar='N', help='runs in up to N processes (default: the available CPUs)')
    parser.set_defaults(run=cmd_identify)


def cmd_identify(args) -> int:
    import dataclasses
    import enum
    import math

    import numpy as np

    from machine_ctrl.experiments import identify
    machine = load_machine(args.machine)
    if args.axis not in machine.axis_names:
        return error('identify', f'{machine.name} has no axis {args.axis!r} (axes: {", ".join(machine.axis_names)})')
    if args.jobs is not None and args.jobs < 1:
        return error('identify', f'--jobs must be a whole number > 0, got {args.jobs}')
    method = identify.method_of(machine, args.axis)
    print(f'identifying {args.axis} of {machine.name} offline on hw_sim ({method}) ...', file=sys.stderr, flush=True)
    result = identify.identify_axis(machine, args.axis, workers=args.jobs)
    if args.json:
        def plain(value):
            if dataclasses.is_dataclass(value):
                return plain(dataclasses.asdict(value))
            if isinstance(value, dict):
                return {k: plain(v) for k, v in value.items()}
            if isinstance(value, (list, tuple, np.ndarray)):
                return [plain(v) for v in value]
            if isinstance(value, float) and math.isnan(value):
                return None                  # JSON has no NaN: a value not there
            return value.value if isinstance(value, enum.Enum) else value
        print(json.dumps(plain(result)))
    else:
        print(identify.table(result))
    if result['status'] != 'ok':
        print(f'machine-ctrl: identify: {result["reason"]}', file=sys.stderr)
        return 1
    if args.out:
        with open(args.out, 'w') as out:
            out.write(identify.yaml_fragment(machine, result))
        print(f'wrote {args.out}', file=sys.stderr)
    return 0
