"""``machine-ctrl``: the user-facing command-line tool.

Stable outputs (scripts rely on them):

* ``machine-ctrl info [MACHINE] [--json]``: the machine. Text is a table for people;
  ``--json`` prints one object: name, description, control_period (s), axes (in axis order:
  name, kind, unit, drive, stroke [lo, hi] or null when unlimited, velocity, acceleration,
  jerk, sensor_resolution, command_limit) and home (q, tool_tip [m], tool_axis).
* ``machine-ctrl fk [MACHINE]``: reads one configuration per line from stdin (whitespace
  separated, axis order of ``info``, SI units; blank lines and lines starting with ``#`` are
  skipped) and prints ``Px Py Pz Oi Oj Ok`` per configuration (tool tip in m and unit tool
  axis, workpiece frame; shortest round-trip float text). A malformed line (wrong count,
  not a number, NaN/inf) prints one line ``line N: problem`` on stderr instead and the next
  line is read; the exit status is then 1. Positions outside the strokes are evaluated all
  the same: forward kinematics is geometry, limits are enforced where motion is planned.

* ``machine-ctrl experiment circle|square|frf [MACHINE] [--json]``: the experiments of thesis
  section 6.3 / Fig. 4.10 on the simulated machine (offline runner); progress on stderr.
  ``--json``: circle/square print ``{"smc": {...}, "dsfd": {...}}`` with mean_x_tracking,
  mean_y_tracking, mean_contour, max_x_tracking, max_y_tracking, max_contour in um; frf
  prints ``{"bandwidth_hz": {"x_c": ..., "x_f": ..., "x_dual": ..., ...}, "frequencies_hz":
  [...], "gain": {...}}``.

* ``machine-ctrl plan PATH --machine M --out DIR [--json] [--feed F]``: plans a toolpath (CSV
  or built-in name) without running it, writes DIR/references.csv (``time,<axes>``, SI) and
  prints traversal time, planning time, max tool-pose deviation and per-axis peak
  |v|, |a|, |j| over the limits (``--json``: one object).

* ``machine-ctrl record DIR [--topics T ...] [--machine M] [--duration S]``: records the
  graph's topics (default: all but /rosout and /parameter_events) into the rosbag2/MCAP
  bag directory DIR until Ctrl-C / SIGTERM / S seconds; prints the messages per topic.
* ``machine-ctrl replay BAG [--rate F] [--topics T ...] [--start-offset S] [--loop]``:
  republishes a bag with its recorded timing (times 1/F), /clock from the recording.
* ``machine-ctrl analyze BAG [BAG2] [--machine M] [--json] [--plots DIR]``: tracking,
  tool-tip contour, drive-limit and fine-stroke statistics of a recorded session; two bags
  side by side. ``--json``: one object (SI units), ``{"runs": [result, ...]}``.
* ``experiment circle|square --record DIR`` also writes each run as a bag, DIR/smc and
  DIR/dsfd.

Bag errors (missing, empty, not MCAP, truncated, missing topics) print one line and exit 2.

MACHINE is a machine name (``config/machines/<name>.yaml``) or a path to such a YAML file;
the default is micromill_9axis. Configuration errors print one line and exit with 2.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from machine_ctrl.model.config import DEFAULT_MACHINE, MachineConfig, load_machine
from machine_ctrl.app.demo import DEFAULT_TURNS as DEMO_TURNS
from machine_ctrl.model.errors import ConfigError
from machine_ctrl.model.kinematics import Kinematics


def _fmt(values) -> str:
    return ' '.join(repr(float(v)) for v in values)


def machine_summary(machine: MachineConfig, kinematics: Kinematics) -> dict:
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


EXPERIMENT_TITLES = {
    'circle': 'Circle R = 30 mm at 600 mm/min on x-y (thesis Table 6.1)',
    'square': 'Square, side 20 mm (assumed), 600 mm/min on x-y (thesis Table 6.2)',
}
STAT_LABELS = ('Mean x-axis tracking', 'Mean y-axis tracking', 'Mean contour',
               'Max x-axis tracking', 'Max y-axis tracking', 'Max contour')


def _progress(label: str, done: int, total: int) -> None:
    print(f'\r{label}: {100 * done // max(total, 1):3d} %', end='' if done < total else '\n',
          file=sys.stderr, flush=True)


def _print_contouring(kind: str, machine: str, result: dict) -> None:
    from machine_ctrl.experiments.tracking import STAT_KEYS, THESIS
    print(f'{EXPERIMENT_TITLES[kind]}; {machine} simulation; errors in um')
    print(f'{"":22s} {"SMC sim":>9s} {"thesis":>9s} {"DSFD sim":>9s} {"thesis":>9s}')
    for key, label in zip(STAT_KEYS, STAT_LABELS):
        i = STAT_KEYS.index(key)
        print(f'{label:22s} {result["smc"][key]:9.3f} {THESIS[kind]["smc"][i]:9.3f} '
              f'{result["dsfd"][key]:9.3f} {THESIS[kind]["dsfd"][i]:9.3f}')
    for key, label in (('max_contour', 'max contour'), ('max_y_tracking', 'max y tracking')):
        i = STAT_KEYS.index(key)
        ours = result['smc'][key] / result['dsfd'][key]
        theirs = THESIS[kind]['smc'][i] / THESIS[kind]['dsfd'][i]
        print(f'SMC/DSFD {label}: {ours:.2f}x (thesis {theirs:.2f}x)')


def _print_frf(machine: str, result: dict) -> None:
    names = list(result['gain'])
    print(f'Closed-loop frequency responses, servo loop alone (thesis Fig. 4.10); {machine} simulation')
    print('   f/Hz ' + ' '.join(f'{n:>8s}' for n in names) + '   (gain, dB)')
    for i, f in enumerate(result['frequencies_hz']):
        print(f'{f:7.1f} ' + ' '.join(f'{20 * math.log10(max(result["gain"][n][i], 1e-12)):8.2f}' for n in names))
    print('-3 dB bandwidth/Hz ' + ' '.join(
        f'{n}={"n/a" if b is None else f"{b:.1f}"}' for n, b in result['bandwidth_hz'].items()))


def _error(command: str, exc: Exception) -> int:
    print(f'machine-ctrl: {command}: {" ".join(str(exc).split())}', file=sys.stderr)
    return 2


def _fresh_directory(path: str) -> None:
    """ValueError unless `path` is absent or an empty directory (a bag goes there)."""
    import os
    if os.path.exists(path) and (not os.path.isdir(path) or os.listdir(path)):
        raise ValueError(f'{path}: exists and is not an empty directory')


def cmd_experiment(args) -> int:
    from machine_ctrl.experiments import tracking as experiments
    machine = load_machine(args.machine)
    progress = None if args.quiet else _progress
    if args.record is not None:
        import os
        try:
            if args.name == 'frf':
                raise ValueError('--record is for circle and square')
            for label in ('smc', 'dsfd'):
                _fresh_directory(os.path.join(args.record, label))
        except ValueError as exc:
            return _error('experiment', exc)
    if args.name == 'frf':
        result = experiments.frf(machine, progress=progress)
        if args.json:
            print(json.dumps({'bandwidth_hz': result['bandwidth_hz'],
                              'frequencies_hz': result['frequencies_hz'], 'gain': result['gain']}))
        else:
            _print_frf(machine.name, result)
        return 0
    result = experiments.contouring(machine, args.name, progress=progress, record_dir=args.record)
    if args.json:
        print(json.dumps(result))
    else:
        _print_contouring(args.name, machine.name, result)
    return 0


def cmd_plan(args) -> int:
    """``plan PATH --machine M --out DIR [--json] [--feed F]``: plan without running, write
    DIR/references.csv (time, then each axis position in info order, SI) and a summary."""
    import os
    import numpy as np
    from trajectory.planner import DEFAULT_FEED, plan
    machine = load_machine(args.machine)
    try:
        result = plan(args.path, machine, feed=DEFAULT_FEED if args.feed is None else args.feed)
        os.makedirs(args.out, exist_ok=True)
        ref = result.reference
        table = np.column_stack((np.arange(len(ref)) * ref.period, ref.position))
        np.savetxt(os.path.join(args.out, 'references.csv'), table, fmt='%.17g', delimiter=',',
                   header='time,' + ','.join(machine.axis_names), comments='')
    except (ValueError, OSError) as exc:
        print(f'machine-ctrl: plan: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    summary = result.summary()
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"traversal time   {summary['traversal_time']:.4f} s ({summary['samples']} samples)")
    print(f"planning time    {summary['planning_time']:.3f} s")
    print(f"max deviation    {summary['max_position_deviation']:.3g} m, "
          f"{summary['max_orientation_deviation']:.3g} rad")
    print('axis  |v|/v_max  |a|/a_max  |j|/j_max')
    for name, r in summary['peak_ratios'].items():
        print(f"{name:5s} {r['velocity']:9.4f}  {r['acceleration']:9.4f}  {r['jerk']:9.4f}")
    return 0


def _ros_args() -> list[str]:
    """rclpy arguments for an in-process node of the CLI (no --ros-args from our argv)."""
    return ['machine-ctrl']


def cmd_record(args) -> int:
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from machine_ctrl.recording import recorder
    from machine_ctrl.ros.recorder_node import RecorderNode, run
    try:
        recorder.wanted_topics(args.topics)
        if args.machine:
            load_machine(args.machine)
        if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
            raise ValueError(f'--duration must be > 0 s, got {args.duration}')
        _fresh_directory(args.output)
    except (ValueError, ConfigError) as exc:
        return _error('record', exc)
    overrides = [Parameter('output', value=args.output), Parameter('topics', value=list(args.topics) or ['']),
                 Parameter('machine', value=args.machine or ''), Parameter('duration', value=float(args.duration or 0.0))]
    rclpy.init(args=_ros_args(), signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = RecorderNode(parameter_overrides=overrides)
        except SystemExit as exc:
            return int(exc.code or 2)
        return run(node)
    finally:
        rclpy.try_shutdown()


def cmd_replay(args) -> int:
    from rclpy.parameter import Parameter

    from machine_ctrl.recording import replay
    from machine_ctrl.ros import replay_node
    from machine_ctrl.recording.bag import Bag
    try:
        replay.check_options(args.rate, args.start_offset)
        with Bag(args.bag) as bag:
            replay.select(bag, args.topics or None, args.start_offset)
    except ValueError as exc:             # BagError is a ValueError
        return _error('replay', exc)
    overrides = [Parameter('bag', value=args.bag), Parameter('rate', value=float(args.rate)),
                 Parameter('topics', value=list(args.topics) or ['']),
                 Parameter('start_offset', value=float(args.start_offset)), Parameter('loop', value=args.loop),
                 Parameter('wait_for_subscribers', value=args.wait_for_subscribers)]
    return replay_node.main(_ros_args(), overrides)


def cmd_analyze(args) -> int:
    from machine_ctrl.recording import analysis
    try:
        runs = [analysis.load(path, args.machine) for path in args.bags]
        if len(runs) == 2:
            analysis.check_comparable(*runs)
        results = [analysis.analyse(run) for run in runs]
    except ValueError as exc:             # BagError, AnalysisError
        return _error('analyze', exc)
    if args.plots:
        from machine_ctrl.recording import plots
        try:
            written = plots.write(results, runs[0].machine, args.plots)
        except OSError as exc:
            return _error('analyze', f'{args.plots}: cannot write plots: {exc.strerror}')
        print(f'plots: {", ".join(str(p) for p in written)}', file=sys.stderr)
    if args.json:
        print(json.dumps({'runs': [analysis.public(r) for r in results]}))
    else:
        print(analysis.table(results, [r.machine for r in runs]))
    return 0


def cmd_bringup(args) -> int:
    from machine_ctrl.app import bringup
    machine = load_machine(args.machine)
    try:
        if args.record is not None:
            _fresh_directory(args.record)
        if args.compensation is not None:
            _readable_model(args.compensation, machine)
    except (ValueError, ConfigError) as exc:
        return _error('bringup', exc)
    return bringup.run(args, machine)


def _readable_model(path: str, machine: MachineConfig) -> None:
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


def goal_outcome(client, after: int, refused: int) -> str | None:
    """'refused', 'fault', 'done' or None (not yet) for a goal sent when `after` statuses
    and `refused` refusals had been seen."""
    status = client.status()
    if int(status.get('rejected_goals', 0)) > refused:
        return 'refused'
    if any(s.message == 'fault' for s in client.statuses[after:]):
        return 'fault'
    return 'done' if client.states_seen(after, ['running', 'idle']) else None


def follow_goal(client, publish, timeout: float, out=sys.stdout) -> int:
    """Send with `publish()`, show the progress until the motion ends; 0 when it ran to
    its end, 1 when refused, faulted, stopped early or timed out (reason on stderr)."""
    import time
    from machine_ctrl.app.bringup import StateReporter
    after, refused = len(client.statuses), int(client.status().get('rejected_goals', 0))
    publish()
    reporter = StateReporter(client, out)
    reporter.seen = after
    deadline = time.monotonic() + timeout
    while (outcome := goal_outcome(client, after, refused)) is None:
        if time.monotonic() > deadline:
            print(f'machine-ctrl: timed out after {timeout:g} s; status {client.status()}', file=sys.stderr)
            return 1
        reporter.poll()
        time.sleep(0.05)
    reporter.poll()
    status = client.status()
    if outcome == 'refused':
        print(f'machine-ctrl: refused: {status["last_rejection"]}', file=sys.stderr)
        return 1
    if outcome == 'fault':
        print(f'machine-ctrl: machine faulted: {status.get("fault", "")}', file=sys.stderr)
        return 1
    progress = float(status.get('progress', 0))
    if progress < 1.0:
        print(f'machine-ctrl: the motion ended at {progress * 100:.1f} % (stopped)', file=sys.stderr)
        return 1
    print(f'done: {status.get("motion", "")}', file=out)
    return 0


def _run_goal(command: str, machine: MachineConfig, timeout: float, send) -> int:
    from machine_ctrl.app.client import Timeout
    if not (math.isfinite(timeout) and timeout > 0):
        return _error(command, ValueError(f'--timeout must be > 0 s, got {timeout}'))
    from machine_ctrl.app.bringup import client_session, listening
    with client_session(machine, 'machine_ctrl_cli') as client:
        try:
            client.wait(lambda: client.statuses and listening(client, client.pub_path)
                        and listening(client, client.pub_goal),
                        'the trajectory node (is the graph up? machine-ctrl bringup)', min(timeout, 30.0))
        except Timeout as exc:
            return _error(command, exc)
        return follow_goal(client, lambda: send(client), timeout)


def cmd_send(args) -> int:
    from trajectory import toolpath
    machine = load_machine(args.machine)
    try:
        cl = toolpath.builtin(args.path) if args.path in toolpath.BUILTIN else toolpath.read_csv(args.path)
    except (ValueError, OSError) as exc:
        return _error('send', exc)
    return _run_goal('send', machine, args.timeout, lambda client: client.send_path(cl))


def cmd_move(args) -> int:
    machine = load_machine(args.machine)
    try:
        names, values = parse_joint_goal(args.goal)
    except ValueError as exc:
        return _error('move', exc)
    return _run_goal('move', machine, args.timeout, lambda client: client.send_goal(names, [values]))


def cmd_demo(args) -> int:
    from machine_ctrl.app import demo
    return demo.run(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='machine-ctrl', description=__doc__.split('\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    info = sub.add_parser('info', help='print the machine: axes, strokes, limits, drives, home pose')
    info.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    info.add_argument('--json', action='store_true', help='one JSON object on stdout')
    info.set_defaults(run=cmd_info)
    fk = sub.add_parser('fk', help='forward kinematics of configurations read from stdin')
    fk.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    fk.set_defaults(run=cmd_fk)
    experiment = sub.add_parser('experiment', help='thesis experiments on the simulated machine')
    experiment.add_argument('name', choices=('circle', 'square', 'frf'))
    experiment.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    experiment.add_argument('--json', action='store_true', help='one JSON object on stdout')
    experiment.add_argument('--quiet', action='store_true', help='no progress on stderr')
    experiment.add_argument('--record', metavar='DIR', help='also write each run as a bag, DIR/smc and DIR/dsfd')
    experiment.set_defaults(run=cmd_experiment)
    plan = sub.add_parser('plan', help='plan a toolpath and write the sampled references')
    plan.add_argument('path', help='CSV file (px,py,pz,oi,oj,ok, SI) or built-in toolpath name')
    plan.add_argument('--machine', default=DEFAULT_MACHINE)
    plan.add_argument('--out', required=True, help='directory for references.csv')
    plan.add_argument('--json', action='store_true', help='one JSON object on stdout')
    plan.add_argument('--feed', type=float, help='process feed limit, m/s (default: the planner\'s, 10 mm/s)')
    plan.set_defaults(run=cmd_plan)
    record = sub.add_parser('record', help='record the graph\'s topics into a rosbag2/MCAP bag directory')
    record.add_argument('output', help='bag directory to create')
    record.add_argument('--topics', nargs='+', default=[], metavar='T',
                        help='topics to record (NAME or NAME:pkg/msg/Type); default: all')
    record.add_argument('--machine', help='machine name or YAML stored with the bag (for analyze)')
    record.add_argument('--duration', type=float, help='stop after this many seconds (wall)')
    record.set_defaults(run=cmd_record)
    replay = sub.add_parser('replay', help='republish a recorded bag')
    replay.add_argument('bag', help='bag directory or .mcap file')
    replay.add_argument('--rate', type=float, default=1.0, help='factor on the recorded timing (default 1)')
    replay.add_argument('--topics', nargs='+', default=[], metavar='T', help='topics to replay (default: all)')
    replay.add_argument('--start-offset', type=float, default=0.0, metavar='S', help='start S seconds into the bag')
    replay.add_argument('--loop', action='store_true', help='replay again and again')
    replay.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                        help='start when every topic has N matched subscribers')
    replay.set_defaults(run=cmd_replay)
    analyze = sub.add_parser('analyze', help='tracking, contour and limit statistics of recorded bags')
    analyze.add_argument('bags', nargs='+', metavar='BAG', help='one bag, or two to compare')
    analyze.add_argument('--machine', help='machine name or YAML (default: the one the bag names)')
    analyze.add_argument('--json', action='store_true', help='one JSON object on stdout (SI units)')
    analyze.add_argument('--plots', metavar='DIR', help='write errors.png, path_xy.png, limits.png into DIR')
    analyze.set_defaults(run=cmd_analyze)
    bring = sub.add_parser('bringup', help='start the whole node graph and wait for commands')
    bring.add_argument('machine', nargs='?', default=DEFAULT_MACHINE)
    bring.add_argument('--single-process', action='store_true', help='every node in one process')
    bring.add_argument('--record', metavar='DIR', help='record the session into this bag directory')
    bring.add_argument('--no-dual-stage', action='store_true', help='start with the dual-stage coupling off')
    bring.add_argument('--compensation', metavar='MODEL', help='geometric error model: compensation on')
    bring.set_defaults(run=cmd_bringup)
    send = sub.add_parser('send', help='send a tool path to the running graph and follow it')
    send.add_argument('path', help='CSV file (px,py,pz,oi,oj,ok, SI) or built-in toolpath name')
    send.add_argument('--machine', default=DEFAULT_MACHINE)
    send.add_argument('--timeout', type=float, default=3600.0, metavar='S', help='give up after S s (wall)')
    send.set_defaults(run=cmd_send)
    move = sub.add_parser('move', help='send a joint goal (AXIS=VALUE ..., m / rad) and follow it')
    move.add_argument('goal', nargs='+', metavar='AXIS=VALUE')
    move.add_argument('--machine', default=DEFAULT_MACHINE)
    move.add_argument('--timeout', type=float, default=600.0, metavar='S', help='give up after S s (wall)')
    move.set_defaults(run=cmd_move)
    demo = sub.add_parser('demo', help='the main job: helix on the 9-axis machine, recorded and analysed')
    demo.add_argument('--out', metavar='DIR', help='output directory (default: a new temporary directory)')
    demo.add_argument('--turns', type=float, default=DEMO_TURNS, help=f'helix turns (default {DEMO_TURNS:g})')
    demo.set_defaults(run=cmd_demo)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['fit-errors'] or argv[:2] == ['experiment', 'geometric']:   # machine_ctrl/app/compensation_cli.py ([6/7])
        from machine_ctrl.app import compensation_cli
        if argv[0] == 'fit-errors':
            return compensation_cli.fit_errors_main(argv[1:])
        return compensation_cli.experiment_main(argv[2:])
    if argv[:2] == ['experiment', 'contour']:            # machine_ctrl/experiments/contour.py ([5/7])
        from machine_ctrl.experiments import contour as contour_experiment
        return contour_experiment.main(argv[2:])
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == 'analyze' and len(args.bags) > 2:
        parser.error('analyze takes one bag or two')
    try:
        return args.run(args)
    except ConfigError as exc:
        print(f'machine-ctrl: {exc}', file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `machine-ctrl fk | head`
        sys.stderr.close()
        return 0


if __name__ == '__main__':
    sys.exit(main())
