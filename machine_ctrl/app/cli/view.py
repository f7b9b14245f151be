"""``machine-ctrl view``: a session in Foxglove (issue [7/8], part 3; README "Live view").

* ``view [--machine M] [--namespace NS] [--host H] [--port P] [--rate HZ]``: the running
  graph, live: the view node (machine_ctrl/ros/view_node.py) in this process, a Foxglove
  WebSocket server on ws://H:P (default 127.0.0.1:8765), until Ctrl-C. ``bringup --view``
  starts the same node with the graph.
* ``view --bag BAG --out FILE.mcap [--machine M] [--period S]``: a recorded session with the
  same channels (machine_ctrl.view.live_view.view_bag), for Foxglove to open as a file with
  the same layout; prints the messages per channel.
* ``view --layout FILE [--machine M] [--namespace NS]``: writes the Foxglove layout of the
  machine's session in NS (config/foxglove/<machine>.json are those of the root namespace).

Exit 2 for bad arguments, a bag that cannot be read or an output that exists (one line).
"""
from __future__ import annotations

from machine_ctrl.app.cli.common import error, namespace_option
from machine_ctrl.parameters import VIEW


def register(subparsers) -> None:
    view = subparsers.add_parser('view', help='the running graph (or a recorded bag) in Foxglove')
    view.add_argument('--machine', help='machine name or YAML (default: micromill_9axis; with --bag the bag\'s)')
    view.add_argument('--host', default=VIEW.spec('host').default, help='address to listen on (default %(default)s)')
    view.add_argument('--port', type=int, default=VIEW.spec('port').default,
                      help='WebSocket port (default %(default)s; 0: any free port, printed)')
    view.add_argument('--rate', type=float, default=VIEW.spec('sample_rate').default, metavar='HZ',
                      help='live: the newest messages of each per-step stream this many times a wall second '
                           '(default %(default)s)')
    view.add_argument('--period', type=float, metavar='S',
                      help='--bag: one message of each per-step stream every S of sim time (default: '
                           'machine_ctrl.view.live_view.ViewConfig, 0.01 s)')
    view.add_argument('--bag', metavar='BAG', help='a recorded session instead of the running graph')
    view.add_argument('--out', metavar='FILE', help='with --bag: the MCAP file to write')
    view.add_argument('--layout', metavar='FILE', help='write the Foxglove layout of the machine (in NS) and exit')
    namespace_option(view)
    view.set_defaults(run=cmd_view, validate=_bag_and_out)


def _bag_and_out(args) -> str | None:
    if (args.bag is None) != (args.out is None):
        return 'view --bag BAG needs --out FILE.mcap, and --out needs --bag'
    if args.bag is not None and args.namespace:
        return 'view --bag takes the namespace the bag recorded, not --namespace'
    return None


def cmd_view(args) -> int:
    from machine_ctrl.model.config import DEFAULT_MACHINE, load_machine
    if args.bag is not None:
        return _view_bag(args)
    if args.layout is not None:
        from machine_ctrl.view.layout import text
        written = text(load_machine(args.machine or DEFAULT_MACHINE), args.namespace)
        try:
            with open(args.layout, 'x') as f:
                f.write(written)
        except OSError as exc:
            return error('view', f'{args.layout}: {exc.strerror}')
        print(f'wrote {args.layout}')
        return 0
    from machine_ctrl.ros import view_node
    ros_args = ['machine-ctrl', '--ros-args', '-p', f'machine:={args.machine or DEFAULT_MACHINE}',
                '-p', f'host:={args.host}', '-p', f'port:={args.port}', '-p', f'sample_rate:={args.rate!r}']
    if args.namespace:
        ros_args += ['-r', f'__ns:={args.namespace}']
    return view_node.main(ros_args)


def _view_bag(args) -> int:
    from pathlib import Path

    from machine_ctrl.view.live_view import ViewConfig, view_bag
    if Path(args.out).exists():
        return error('view', f'{args.out} exists; give a new file')
    try:
        config = ViewConfig() if args.period is None else ViewConfig(period=args.period)
        view = view_bag(args.bag, args.out, args.machine, config)
    except (ValueError, OSError) as exc:     # BagError, AnalysisError, a bad period; the output not writable
        Path(args.out).unlink(missing_ok=True)          # no partial file left to refuse the next try
        return error('view', exc)
    for topic in sorted(view.counts):
        print(f'{topic}: {view.forwarded[topic]} of {view.counts[topic]} messages'
              + (f' (skipped: {view.skipped[topic]})' if topic in view.skipped else ''))
    print(f'wrote {args.out}: open it in Foxglove with the layout config/foxglove/{view.machine.name}.json')
    return 0
