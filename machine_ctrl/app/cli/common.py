"""Helpers shared by the command groups: one-line errors, output-directory checks."""
from __future__ import annotations

import os
import sys


def error(command: str, exc) -> int:
    """Print ``machine-ctrl: COMMAND: problem`` (one line) on stderr; exit status 2."""
    print(f'machine-ctrl: {command}: {" ".join(str(exc).split())}', file=sys.stderr)
    return 2


def fresh_directory(path: str) -> None:
    """ValueError unless `path` is absent or an empty directory (a bag goes there)."""
    if os.path.exists(path) and (not os.path.isdir(path) or os.listdir(path)):
        raise ValueError(f'{path}: exists and is not an empty directory')


def namespace_option(parser) -> None:
    """``--namespace NS``: the graph's ROS namespace (default the root), checked at parse
    time and normalized ('mill1' -> '/mill1')."""
    parser.add_argument('--namespace', type=_namespace, default='', metavar='NS',
                        help="ROS namespace of the graph (e.g. mill1; default: the root '/')")


def _namespace(text: str) -> str:
    import argparse

    from machine_ctrl import contract
    try:
        return contract.normal_namespace(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def whole_number(text: str) -> int:
    """argparse type: an int > 0, else the reason (argparse prints it)."""
    import argparse
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value <= 0:
        raise argparse.ArgumentTypeError(f'must be a whole number > 0, got {text!r}')
    return value
