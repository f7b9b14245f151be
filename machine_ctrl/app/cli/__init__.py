"""``machine-ctrl``: the user-facing command-line tool.

This package is the CLI tree: here the root parser and ``main`` (the console script
``machine_ctrl.app.cli:main``; also ``python -m machine_ctrl.app.cli``), and one module per
command group, each exposing ``register(subparsers)`` that adds its subcommands, with their
stable outputs documented in the module:

* machine.py: ``info [MACHINE] [--json]``, ``fk [MACHINE]``;
* experiment.py: ``experiment circle|square|frf|contour|geometric ...`` (geometric is
  registered by errors.py) and the seed-table experiments (midrange, piezo-milling,
  deflection, feed-force, fts-*);
* plan.py: ``plan PATH --machine M --out DIR [--json] [--feed F]``;
* recording.py: ``record DIR ...``, ``replay BAG ...``, ``analyze BAG [BAG2] ...``;
* graph.py: ``bringup [MACHINE] ...``, ``send PATH ...``, ``move AXIS=VALUE ...``, ``freeform``, ``demo``;
* view.py: ``view [--bag BAG --out FILE]`` (Foxglove);
* errors.py: ``fit-errors CSV ...`` (the geometric error model);
* identify.py: ``identify AXIS [--machine M] [--out FILE] [--json] [--jobs N]`` (by the axis's
  drive: a feed drive, a flexure stage or a piezo stage, offline on hw_sim).

A group sets on each of its subparsers ``run`` (the handler: args -> exit status), and
optionally ``validate`` (args -> problem text or None; a problem is a usage error) and
``usage_parser`` (the subparser that reports unrecognized arguments with its own usage;
default: the root parser, as argparse does). Handlers import heavy modules (numpy,
Pinocchio, rclpy, the cores) inside the handler, so that building the parser stays cheap
and ``machine-ctrl info`` fast. The group modules import one another only through
common.py (and experiment.py -> errors.py); nothing imports this package but the entry
points (and the launch file, common.py).

MACHINE is a machine name (``config/machines/<name>.yaml``) or a path to such a YAML file;
the default is micromill_9axis. Bad arguments print the usage and one line
``machine-ctrl...: error: ...`` and exit 2; configuration errors print one line
``machine-ctrl: <file>: <key>: <problem>`` and exit 2.
"""
from __future__ import annotations

import argparse
import sys

from machine_ctrl.app.cli import errors, experiment, graph, identify, machine, plan, recording, view
from machine_ctrl.model.errors import ConfigError

# in the order of the root help
COMMAND_GROUPS = (machine, experiment, plan, recording, graph, view, errors, identify)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='machine-ctrl', description=__doc__.split('\n')[0])
    subparsers = parser.add_subparsers(dest='command', required=True)
    for group in COMMAND_GROUPS:
        group.register(subparsers)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    args, unrecognized = parser.parse_known_args(argv)
    if unrecognized:
        getattr(args, 'usage_parser', parser).error(f'unrecognized arguments: {" ".join(unrecognized)}')
    problem = args.validate(args) if hasattr(args, 'validate') else None
    if problem:
        parser.error(problem)
    try:
        return args.run(args)
    except ConfigError as exc:
        print(f'machine-ctrl: {exc}', file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `machine-ctrl fk | head`
        sys.stderr.close()
        return 0
