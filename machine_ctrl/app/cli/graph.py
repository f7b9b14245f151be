"""``machine-ctrl bringup|send|move|freeform|demo``: the running node graph
(machine_ctrl.app.bringup starts it; send, move and freeform are clients of its trajectory
node, machine_ctrl.app.goals follows their goals by id; demo is machine_ctrl.app.demo).
send takes a G-code program too: its pieces one goal after the other (:func:`_send_program`).
bringup, send, move and freeform take the graph's ``--namespace`` (default the root).

send, move and freeform wait for the graph to be ready (hw_sim's latched ready, at most 30 s: else
exit 2 "the graph is not ready after 30 s: is it up? machine-ctrl bringup"), then for the
trajectory node to hear the goal topic, stamp and publish the goal, and follow it: exit 0
when it succeeded, 1 when refused, aborted, canceled or timed out (the reason on stderr),
2 for bad arguments."""
from __future__ import annotations

import math
import sys
import time

from machine_ctrl.app.cli.common import error, fresh_directory, namespace_option
from machine_ctrl.app.demo import DEFAULT_TURNS as DEMO_TURNS
from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.parameters import HW_SIM, VIEW, validate

VIEW_PORT = VIEW.spec('port').default


def real_time_factor(text: str) -> float:
    """argparse type: hw_sim's real_time_factor, checked by its parameter's own rule."""
    import argparse
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a number, got {text!r}') from None
    if (problem := validate(HW_SIM.spec('real_time_factor'), value)) is not None:
        raise argparse.ArgumentTypeError(problem)
    return value


def register(subparsers) -> None:
    bring = subparsers.add_parser('bringup', help='start the whole node graph and wait for commands')
    bring.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    bring.add_argument('--single-process', action='store_true', help='every node in one process')
    bring.add_argument('--record', metavar='DIR', help='record the session into this bag directory')
    bring.add_argument('--stop-on-recording-loss', action='store_true',
                       help='with --record: stop the whole graph if the recording stops (recorder killed, disk '
                            'full); default: say so and keep the machine running')
    bring.add_argument('--paced', action='store_true',
                       help='hw_sim steps on the wall clock, as real hardware does, counting missed deadlines and '
                            'the step latency in its diagnostics (default: lock-step, every command awaited)')
    bring.add_argument('--real-time-factor', type=real_time_factor, metavar='F',
                       help='with --paced: sim time per wall time, in (0, 1] (default 1)')
    bring.add_argument('--no-dual-stage', action='store_true', help='start with the dual-stage coupling off')
    bring.add_argument('--compensation', metavar='MODEL', help='geometric error model: compensation on')
    bring.add_argument('--identified', metavar='FILE', action='append', default=[],
                       help="the servos take the controllers' values from FILE (machine-ctrl identify --out) over "
                            "the machine's; hw_sim keeps the machine's plant (repeat for several axes)")
    bring.add_argument('--view', type=int, nargs='?', const=VIEW_PORT, metavar='PORT',
                       help=f'the Foxglove live view on ws://127.0.0.1:PORT (default {VIEW_PORT}; 0: any free port, '
                            'printed in the view\'s log)')
    namespace_option(bring)
    bring.set_defaults(run=cmd_bringup)
    send = subparsers.add_parser('send', help='send a tool path to the running graph and follow it')
    send.add_argument('path', help='CSV file (px,py,pz,oi,oj,ok, SI), built-in toolpath name or G-code program '
                      '(.ngc .nc .gcode .tap: its pieces one after the other)')
    send.add_argument('--machine', default=DEFAULT_MACHINE)
    send.add_argument('--timeout', type=float, default=3600.0, metavar='S', help='give up after S s (wall)')
    namespace_option(send)
    send.set_defaults(run=cmd_send)
    move = subparsers.add_parser('move', help='send a joint goal (AXIS=VALUE ..., m / rad) and follow it')
    move.add_argument('goal', nargs='+', metavar='AXIS=VALUE')
    move.add_argument('--machine', default=DEFAULT_MACHINE)
    move.add_argument('--timeout', type=float, default=600.0, metavar='S', help='give up after S s (wall)')
    namespace_option(move)
    move.set_defaults(run=cmd_move)
    cut = subparsers.add_parser('freeform', help='a spindle-slaved freeform cut (Ding Ch. 8) on the running graph, '
                                'followed: the trajectory node\'s freeform.* parameters, then its freeform service')
    cut.add_argument('surface', nargs='?', help='sinusoidal_grid, beam_integrator, micro_lens_array or a CSV surface table '
                     '(default: the node\'s freeform.surface)')
    for flag, name, text in (('--rpm', 'spindle_speed', 'spindle speed, rpm'),
                             ('--feed-per-rev', 'feed_per_rev', 'radial feed per revolution, m'),
                             ('--radius', 'start_radius', 'start radius, m'), ('--duration', 'duration', 'cut, s'),
                             ('--angle', 'start_angle', 'start angle, rad'),
                             ('--lead', 'lead', 'landing and lift-off time of the fast axis, s')):
        cut.add_argument(flag, dest=name, type=float, help=f'{text} (default: the node\'s freeform.{name})')
    cut.add_argument('--machine', default=DEFAULT_MACHINE)
    cut.add_argument('--timeout', type=float, default=3600.0, metavar='S', help='give up after S s (wall)')
    namespace_option(cut)
    cut.set_defaults(run=cmd_freeform)
    demo = subparsers.add_parser('demo', help='the main job: helix on the 9-axis machine, recorded and analysed')
    demo.add_argument('--out', metavar='DIR', help='output directory (default: a new temporary directory)')
    demo.add_argument('--turns', type=float, default=DEMO_TURNS, help=f'helix turns (default {DEMO_TURNS:g})')
    demo.set_defaults(run=cmd_demo)


def cmd_bringup(args) -> int:
    from machine_ctrl.app import bringup
    if args.real_time_factor is not None and not args.paced:
        return error('bringup', ValueError('--real-time-factor needs --paced'))
    machine = load_machine(args.machine)
    if args.identified:                       # a bad belief file: one line here, not a dead node
        load_machine(args.machine, belief=args.identified)
    try:
        if args.record is not None:
            fresh_directory(args.record)
        if args.compensation is not None:
            _readable_model(args.compensation, machine)
    except (ValueError, ConfigError) as exc:
        return error('bringup', exc)
    return bringup.run(args, machine)


def _readable_model(path: str, machine) -> None:
    """ConfigError (one line) unless `path` is a geometric error model for `machine`."""
    from compensation.error_map import load_error_map
    load_error_map(path, machine.axis_names)


def parse_joint_goal(items) -> tuple[list[str], list[float]]:
    """``name=value`` words -> names, values; ValueError names the bad word."""
    names, values = [], []
    for item in items:
        name, sep, text = item.partition('=')
        if not sep or not name:
            raise ValueError(f'{item!r}: expected AXIS=VALUE (m or rad), e.g. x_c=0.01')
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f'{item!r}: {text!r} is not a number') from None
        if not math.isfinite(value):
            raise ValueError(f'{item!r}: the value is not finite')
        names.append(name)
        values.append(value)
    return names, values


def _run_goal(command: str, machine, timeout: float, send, namespace: str = '', known_id=None) -> int:
    """Wait for the graph (ready, the trajectory node listening), then send(client, stamp)
    and follow the goal."""
    from machine_ctrl.app.goals import follow_goal
    return _with_graph(command, machine, timeout, namespace,
                       lambda client: follow_goal(client, lambda stamp: send(client, stamp), timeout,
                                                  known_id=known_id))


def _with_graph(command: str, machine, timeout: float, namespace: str, run) -> int:
    """run(client) once the graph is ready and the trajectory node listens; its exit status."""
    from machine_ctrl.app.client import READY_TIMEOUT, Timeout
    if not (math.isfinite(timeout) and timeout > 0):
        return error(command, ValueError(f'--timeout must be > 0 s, got {timeout}'))
    from machine_ctrl.app.bringup import client_session
    with client_session(machine, 'machine_ctrl_cli', namespace=namespace) as client:
        started = time.monotonic()
        try:
            client.wait_ready(min(timeout, READY_TIMEOUT))
            client.wait_listening(max(min(timeout, READY_TIMEOUT) - (time.monotonic() - started), 1.0))
        except Timeout as exc:
            return error(command, exc)
        return run(client)


def _send_program(args, machine) -> int:
    """A G-code program on the graph: its pieces (trajectory.gcode) one after the other, each
    a tool path goal with the trajectory node's feed set to the piece's (restored at the
    end), followed to its end; the first that does not succeed ends the program (exit 1,
    naming its lines). An M0 waits for a line on stdin (Enter): at its end (a closed stdin)
    the program stops there, exit 1 — a mandatory stop is never run through unattended.
    The node plans each piece from where the machine stands (as ``plan`` from where the
    piece before ended: the same place, up to the servos' error)."""
    from machine_ctrl.app.client import Timeout
    from machine_ctrl.app.goals import follow_goal
    from machine_ctrl.model.kinematics import Kinematics
    from trajectory import gcode
    read = gcode.read(args.path)
    if not read.ok:
        return error('send', read.reason)
    try:
        cut = gcode.pieces(read.program, gcode.tool_axis_of(Kinematics.from_config(machine), machine))
    except gcode.GcodeError as exc:
        return error('send', f'{args.path}:{exc.line}: {exc}')
    if not cut:
        return error('send', f'{args.path}: no motion in the program')
    for note in read.program.notes:
        print(f'note: {note}', flush=True)
    deadline = time.monotonic() + args.timeout

    def run(client) -> int:
        try:
            feed = client.get_parameters('trajectory', ['feed'])['feed']
        except Timeout as exc:
            return error('send', exc)
        try:
            for n, piece in enumerate(cut, start=1):
                print(f'piece {n} of {len(cut)}: {piece.where}, {piece.label}', flush=True)
                refused = client.set_parameters('trajectory', {'feed': piece.feed})
                if refused:
                    return error('send', f'the trajectory node refused the feed of {piece.where}: '
                                         + '; '.join(refused))
                left = deadline - time.monotonic()
                if left <= 0:
                    print(f'machine-ctrl: timed out after {args.timeout:g} s, before {piece.where} (piece {n} of '
                          f'{len(cut)})', file=sys.stderr)
                    return 1
                status = follow_goal(client, lambda stamp, cl=piece.cl: client.send_path(cl, stamp=stamp), left)
                if status != 0:
                    print(f'machine-ctrl: send: the program stopped at {piece.where} (piece {n} of {len(cut)})',
                          file=sys.stderr)
                    return status
                if piece.stop_after and n < len(cut):
                    print(f'M0 after line {piece.lines[1]}: program stop; Enter goes on', flush=True)
                    if not sys.stdin.readline():
                        print(f'machine-ctrl: send: M0 after line {piece.lines[1]}: the program stops there '
                              '(stdin is closed; a line on stdin goes on)', file=sys.stderr)
                        return 1
        except Timeout as exc:
            return error('send', exc)
        finally:
            try:
                refused = client.set_parameters('trajectory', {'feed': feed})
            except Timeout as exc:
                refused = [str(exc)]
            if refused:
                print(f'machine-ctrl: send: the trajectory node\'s feed was not restored to {feed:g} m/s: '
                      + '; '.join(refused), file=sys.stderr)
        return 0
    return _with_graph('send', machine, args.timeout, args.namespace, run)


def cmd_send(args) -> int:
    from trajectory import part_program, toolpath
    machine = load_machine(args.machine)
    if part_program.is_program(args.path):
        return _send_program(args, machine)
    try:
        cl = toolpath.builtin(args.path) if args.path in toolpath.BUILTIN else toolpath.read_csv(args.path)
    except (ValueError, OSError) as exc:
        return error('send', exc)
    return _run_goal('send', machine, args.timeout, lambda client, stamp: client.send_path(cl, stamp=stamp),
                     args.namespace)


def cmd_move(args) -> int:
    machine = load_machine(args.machine)
    try:
        names, values = parse_joint_goal(args.goal)
    except ValueError as exc:
        return error('move', exc)
    return _run_goal('move', machine, args.timeout,
                     lambda client, stamp: client.send_goal(names, [values], stamp=stamp), args.namespace)


def cmd_freeform(args) -> int:
    """Set the freeform.* parameters given (the others stay as the node has them), call the
    freeform service and follow the goal it answers with."""
    import re
    from machine_ctrl import contract
    machine = load_machine(args.machine)
    values = {f'freeform.{name}': value for name, value in (
        ('surface', args.surface), ('spindle_speed', None if args.spindle_speed is None else args.spindle_speed * math.pi / 30),
        ('feed_per_rev', args.feed_per_rev), ('start_radius', args.start_radius), ('duration', args.duration),
        ('start_angle', args.start_angle), ('lead', args.lead)) if value is not None}
    started: list[str] = []

    def send(client, stamp):
        refused = client.set_parameters('trajectory', values)
        if refused:
            raise Refused('; '.join(refused))
        ok, message = client.call(contract.FREEFORM.name)
        goal = re.search(r'\(goal ([0-9a-f-]{36})\)', message)
        if not ok or goal is None:
            raise Refused(message)
        started.append(goal.group(1))
    from machine_ctrl.app.client import Timeout
    try:
        return _run_goal('freeform', machine, args.timeout, send, args.namespace, known_id=lambda: started[0])
    except Refused as exc:
        print(f'machine-ctrl: refused: {exc}', file=sys.stderr)
        return 1
    except Timeout as exc:
        print(f'machine-ctrl: freeform: {exc}', file=sys.stderr)
        return 1


class Refused(Exception):
    """The graph refused the request (its reason)."""


def cmd_demo(args) -> int:
    from machine_ctrl.app import demo
    return demo.run(args)
