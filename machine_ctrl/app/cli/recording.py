"""``machine-ctrl record|replay|analyze``: bags of the graph (machine_ctrl.recording, the
recorder and replay nodes of machine_ctrl.ros).

* ``record DIR [--topics T ...] [--machine M] [--duration S] [--namespace NS]``: records the
  topics of the graph in namespace NS (default: all of it but /rosout and
  /parameter_events) into the rosbag2/MCAP bag directory DIR
  until Ctrl-C / SIGTERM / S seconds; prints the messages per topic. Exit 1 if the
  recording stopped early (a write failed: disk full, ...; the bag then needs --recover).
* ``record --recover BAG``: a bag whose recorder was killed (or whose disk filled up) has no
  summary and no metadata.yaml; this rebuilds them from every complete chunk (like ``ros2
  bag reindex``), keeps the damaged file as ``<name>.mcap.damaged``, and prints what was
  recovered (messages per topic), what was lost (bytes after the last complete record)
  and where the custom_data came from. A complete bag is left alone (a missing
  metadata.yaml is rewritten). machine_ctrl.recording.bag.recover.
* ``replay BAG [--rate F] [--topics T ...] [--start-offset S] [--loop]``: republishes a bag
  with its recorded timing (times 1/F), /clock from the recording.
* ``analyze BAG [BAG2] [--machine M] [--json] [--plots DIR]``: tracking, tool-tip contour,
  drive-limit and fine-stroke statistics of a recorded session; two bags side by side.
  ``--json``: one object (SI units), ``{"runs": [result, ...]}``.

Bag errors (missing, empty, not MCAP, truncated, missing topics) print one line and exit 2.
"""
from __future__ import annotations

import json
import math
import sys

from machine_ctrl.app.cli.common import error, fresh_directory, namespace_option
from machine_ctrl.model.config import load_machine
from machine_ctrl.model.errors import ConfigError


def register(subparsers) -> None:
    record = subparsers.add_parser('record', help='record the graph\'s topics into a rosbag2/MCAP bag directory')
    record.add_argument('output', nargs='?', help='bag directory to create')
    record.add_argument('--recover', metavar='BAG',
                        help='rebuild the index, summary and metadata.yaml of a bag whose recorder did not close it '
                             '(killed, disk full): every complete chunk is kept')
    record.add_argument('--topics', nargs='+', default=[], metavar='T',
                        help='topics to record (NAME or NAME:pkg/msg/Type); default: all')
    record.add_argument('--machine', help='machine name or YAML stored with the bag (for analyze)')
    record.add_argument('--duration', type=float, help='stop after this many seconds (wall)')
    namespace_option(record)
    record.set_defaults(run=cmd_record, validate=_output_or_recover)
    replay = subparsers.add_parser('replay', help='republish a recorded bag')
    replay.add_argument('bag', help='bag directory or .mcap file')
    replay.add_argument('--rate', type=float, default=1.0, help='factor on the recorded timing (default 1)')
    replay.add_argument('--topics', nargs='+', default=[], metavar='T', help='topics to replay (default: all)')
    replay.add_argument('--start-offset', type=float, default=0.0, metavar='S', help='start S seconds into the bag')
    replay.add_argument('--loop', action='store_true', help='replay again and again')
    replay.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                        help='start when every topic has N matched subscribers')
    replay.set_defaults(run=cmd_replay)
    analyze = subparsers.add_parser('analyze', help='tracking, contour and limit statistics of recorded bags')
    analyze.add_argument('bags', nargs='+', metavar='BAG', help='one bag, or two to compare')
    analyze.add_argument('--machine', help='machine name or YAML (default: the one the bag names)')
    analyze.add_argument('--json', action='store_true', help='one JSON object on stdout (SI units)')
    analyze.add_argument('--plots', metavar='DIR', help='write errors.png, path_xy.png, limits.png into DIR')
    analyze.set_defaults(run=cmd_analyze, validate=_one_or_two_bags)


def _output_or_recover(args) -> str | None:
    if args.recover is None:
        return None if args.output else 'record needs the bag directory to create (or --recover BAG)'
    if args.output or args.topics or args.machine or args.duration is not None:
        return 'record --recover BAG takes no other argument'
    return None


def _one_or_two_bags(args) -> str | None:
    return 'analyze takes one bag or two' if len(args.bags) > 2 else None


def _ros_args() -> list[str]:
    """rclpy arguments for an in-process node of the CLI (no --ros-args from our argv)."""
    return ['machine-ctrl']


def cmd_record(args) -> int:
    from machine_ctrl.recording import recorder
    if args.recover is not None:
        try:
            result = recorder.recover(args.recover)
        except ValueError as exc:          # BagError
            return error('record', exc)
        print(result.report(), flush=True)
        return 0
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from machine_ctrl.ros.recorder_node import RecorderNode, run
    try:
        recorder.wanted_topics(args.topics, args.namespace)
        if args.machine:
            load_machine(args.machine)
        if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
            raise ValueError(f'--duration must be > 0 s, got {args.duration}')
        fresh_directory(args.output)
    except (ValueError, ConfigError) as exc:
        return error('record', exc)
    overrides = [Parameter('output', value=args.output), Parameter('topics', value=list(args.topics) or ['']),
                 Parameter('machine', value=args.machine or ''), Parameter('duration', value=float(args.duration or 0.0))]
    rclpy.init(args=_ros_args(), signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = RecorderNode(namespace=args.namespace or None, parameter_overrides=overrides)
        except SystemExit as exc:
            return int(exc.code or 2)
        return run(node)
    finally:
        rclpy.try_shutdown()


def cmd_replay(args) -> int:
    from rclpy.parameter import Parameter

    from machine_ctrl.recording import replay
    from machine_ctrl.recording.bag import Bag
    from machine_ctrl.ros import replay_node
    try:
        replay.check_options(args.rate, args.start_offset)
        with Bag(args.bag) as bag:
            replay.select(bag, args.topics or None, args.start_offset)
    except ValueError as exc:             # BagError is a ValueError
        return error('replay', exc)
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
        return error('analyze', exc)
    if args.plots:
        from machine_ctrl.recording import plots
        try:
            written = plots.write(results, runs[0].machine, args.plots)
        except OSError as exc:
            return error('analyze', f'{args.plots}: cannot write plots: {exc.strerror}')
        print(f'plots: {", ".join(str(p) for p in written)}', file=sys.stderr)
    if args.json:
        print(json.dumps({'runs': [analysis.public(r) for r in results]}))
    else:
        print(analysis.table(results, [r.machine for r in runs]))
    return 0
