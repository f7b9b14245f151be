"""``machine-ctrl bringup``: the whole node graph of a machine, ready for commands.

hw_sim, the servo nodes, dual_stage, trajectory, contour_error and (with a model)
compensation, each in its own process under :class:`machine_ctrl.app.processes.Supervisor`, or
all in one process (``python -m machine_ctrl.ros.graph``); with ``record`` the recorder runs in
a process of its own (always: it must close its bag) and hw_sim holds at step 0 until it is
matched. :class:`Bringup` waits until every node is on the ROS graph and hw_sim says the
graph is ready (contract.READY: it has completed its first step, so every node has its first
state), follows /trajectory/status, and stops everything (graph first, then the recorder,
which drains, closes the bag and prints its per-topic counts). With a `namespace` every node
(the recorder too) runs in it, and so must the clients (:func:`client_session`).

Losing the recording does not stop the machine: once the graph is ready, a recorder process
that ends on its own (killed, crashed) is reported with one line ("recording stopped:
recorder exited with ...; the bag may need machine-ctrl record --recover DIR") and the graph
keeps running (hw_sim stops holding for a recorder that left the graph); so does a recorder
that reports on /diagnostics that its recording stopped (disk full: it stays up). With
``stop_on_recording_loss`` (``--stop-on-recording-loss``) either stops everything instead
(:class:`RecordingLost`). Before the graph is ready a recorder's end stops the bringup as
any node's does: hw_sim waits at step 0 for it (min_subscribers). The session's exit status
is 1 when the recording was lost.

A node process of the graph that ends on its own once the graph is ready is started again as
the launch file does (:func:`respawn_delay`: once its death has certainly been detected, at
most :data:`RESPAWN_MAX` times), with one line for the shell each time; the graph keeps
running meanwhile (a dead servo or dual_stage node faults hw_sim, which names its axes;
`/hw_sim/reset` continues once the new node answers). Not started again: hw_sim (the
machine: its end stops the bringup, a new bringup is a new machine), a node that exited 0
(asked to stop from outside), a node past its limit (one line; the graph runs on, faulted
if it was a controller). One process (``single_process``): the process is the graph, its end
stops the bringup.

The shell is :func:`run`: prints the command API (:data:`API`), the state changes, and
stops on Ctrl-C / SIGTERM. The demo (:mod:`machine_ctrl.app.demo`) drives a :class:`Bringup`
from the same process.
"""
from __future__ import annotations

import contextlib
import signal
import sys
import tempfile
import time
from pathlib import Path

from machine_ctrl import contract
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.ros.graph import NodeSpec, default_graph, single_process_argv
from machine_ctrl.app.processes import ChildExited, Supervisor, exit_code_text

READY_TIMEOUT = 120.0          # s (wall) for every node to come up
RECORDER_STOP_TIMEOUT = 60.0   # s the recorder may take to drain and close before SIGTERM
# node classes that keep a /joint_states subscription (the trajectory node drops its own
# after the first state): hw_sim's min_subscribers counts them plus the recorder
JOINT_STATE_READERS = {'ServoNode', 'DualStageNode', 'ContourErrorNode'}
# node classes that answer every state on a topic of contract.STEP_ANSWERS: the recorder
# waits for a message of each before it subscribes /joint_states (its start_streams)
STEP_ANSWERERS = {'ServoNode', 'DualStageNode'}
RECORDER_WINDOW = 100          # steps hw_sim may run ahead of the recorder (README: recommended)
# assumed: a node is started again 1 s after its death has certainly been detected: hw_sim's
# command_timeout (a dead servo or dual_stage node) or the liveliness lease and its
# confirmation (a dead compensation node, seen by the trajectory node), whichever is longer.
# So a death is always a fault first (the successor starts without its state: integrators,
# filters, estimates), never a silent continuation — with a 1 s delay a successor that started
# fast answered the held step within the timeout and the machine went on (a loaded run); the
# 1 s also lets the dying process release its DDS entities. 3 retries tell a transient crash
# from one that repeats (then the fault stays, named). bringup and the launch file alike.
RESPAWN_MARGIN = 1.0           # s
RESPAWN_MAX = 3
NOT_RESPAWNED = ('hw_sim', 'recorder')

# (topic or service, type, what) of the command API, as printed by bringup
API = [(item.name, item.type.replace('/msg/', '/').replace('/srv/', '/'), item.description)
       for item in contract.COMMAND_API]


def graph_specs(machine: MachineConfig, dual_stage: bool = True, compensation: str | None = None,
                record: bool = False, namespace: str = '', belief=(), paced: float | None = None) -> list[NodeSpec]:
    """The bringup graph: the default graph with the trajectory node and contour_error, in
    `namespace`, the servo nodes with the controllers' values of the `belief` files. hw_sim
    steps in lock-step, or with `paced` (a real-time factor in (0, 1]; ValueError outside) on
    the wall clock. With a recording in lock-step, hw_sim waits at step 0 for every
    joint-state reader and the recorder and holds for the recorder; paced, it waits for no
    one (real hardware does not): the recorder may miss the first steps and, falling behind,
    lose states (it counts them)."""
    hw_sim = None if paced is None else {'mode': 'paced', 'real_time_factor': paced}
    specs = default_graph(machine, contour=None, dual_stage=dual_stage, hw_sim=hw_sim, compensation_model=compensation,
                          contour_error=True, namespace=namespace, belief=belief)
    return held_for_recorder(specs, RECORDER_WINDOW) if record and paced is None else specs


def held_for_recorder(specs: list[NodeSpec], window: int) -> list[NodeSpec]:
    """`specs` with hw_sim waiting at step 0 for every joint-state reader and a recorder, and
    then running at most `window` steps ahead of the recorder's progress."""
    hw = {'min_subscribers': sum(spec.cls in JOINT_STATE_READERS for spec in specs) + 1, 'recorder_window': window,
          'wait_for_recorder': True}
    return [NodeSpec(s.name, s.module, s.cls, {**s.parameters, **hw}, s.namespace) if s.name == 'hw_sim' else s
            for s in specs]


def recorder_spec(machine: MachineConfig, output: str, graph: list[NodeSpec], namespace: str = '') -> NodeSpec:
    """The recorder of `graph`: it waits for the first answer of each of its step nodes, and
    keeps the graph's session facts with the bag (:func:`session_facts`)."""
    return NodeSpec('recorder', 'machine_ctrl.ros.recorder_node', 'RecorderNode',
                    {'output': str(output), 'machine': str(machine.yaml_path),
                     'start_streams': sum(spec.cls in STEP_ANSWERERS for spec in graph),
                     'session': session_facts(graph) or ['']}, namespace=namespace)


def session_facts(graph: list[NodeSpec]) -> list[str]:
    """How `graph` runs, as the recorder's KEY=VALUE facts: hw_sim's `mode` (and
    `real_time_factor` when paced), and the servos' belief files (`belief_1`, `belief_2`, ...:
    the controllers' values were those, not the machine config's)."""
    hw_sim = next((spec for spec in graph if spec.name == 'hw_sim'), None)
    if hw_sim is None:
        return []
    values = {**hw_sim.table.defaults(), **hw_sim.parameters}
    facts = [f'mode={values["mode"]}']
    if values['mode'] == 'paced':
        facts.append(f'real_time_factor={values["real_time_factor"]!r}')
    belief = next((spec.parameters.get('belief') for spec in graph if spec.parameters.get('belief')), [])
    return facts + [f'belief_{i}={path}' for i, path in enumerate(belief, 1)]


def respawn_delay(specs: list[NodeSpec]) -> float:
    """Seconds from a node's death to its new start: the longer of hw_sim's command_timeout
    in this graph (its spec's value, else its default) and the liveliness lease with its
    confirmation, + RESPAWN_MARGIN (8.5 s by default)."""
    hw_sim = next(spec for spec in specs if spec.name == 'hw_sim')
    timeout = {**hw_sim.table.defaults(), **hw_sim.parameters}['command_timeout']
    return max(timeout, contract.LIVELINESS_LEASE + contract.LOSS_CONFIRM) + RESPAWN_MARGIN


def exit_text(child) -> str:
    """How a supervised process ended, and where its log is: 'code -9 (killed by SIGKILL)
    (its log: ...)'."""
    return exit_code_text(child.returncode) + (f' (its log: {child.log_path})' if child.log_path else '')


def view_spec(machine: MachineConfig, port: int, namespace: str = '') -> NodeSpec:
    """The Foxglove live view of the graph (machine_ctrl/ros/view_node.py), on `port`."""
    return NodeSpec('view', 'machine_ctrl.ros.view_node', 'ViewNode',
                    {'machine': str(machine.yaml_path), 'port': port}, namespace=namespace)


class RecordingLost(RuntimeError):
    """The recording stopped and the session asked to stop with it."""


def recording_lost_text(reason: str, bag: str | None) -> str:
    return f'recording stopped: {reason}; the bag may need machine-ctrl record --recover {bag}'


class Bringup:
    """The running graph. Context manager: leaving the block stops everything.
    ``recording_lost``: why the recording stopped while the graph ran on (None: it did not)."""

    def __init__(self, machine: MachineConfig, *, single_process: bool = False, record: str | None = None,
                 dual_stage: bool = True, compensation: str | None = None, env=None,
                 log_dir: str | None = None, namespace: str = '', stop_on_recording_loss: bool = False,
                 view: int | None = None, belief=(), paced: float | None = None):
        self.machine, self.single_process, self.record = machine, single_process, record
        self.view = view                    # the live view's port (None: no view)
        self.stop_on_recording_loss = stop_on_recording_loss
        self.ready = False
        self.recording_lost: str | None = None
        self.notices: list[str] = []        # lines for the shell (recording lost), taken by run()
        self.namespace = namespace
        self.specs = graph_specs(machine, dual_stage, compensation, record is not None, namespace, belief, paced)
        self.dual_stage, self.compensation = dual_stage, compensation
        self.log_dir = Path(log_dir or tempfile.mkdtemp(prefix='machine_ctrl_bringup_'))
        self.graph = Supervisor(env, log_dir=self.log_dir, stop_timeout=5.0)
        self.recorder = Supervisor(env, log_dir=self.log_dir, stop_timeout=RECORDER_STOP_TIMEOUT)
        self.viewer = Supervisor(env, log_dir=self.log_dir, stop_timeout=5.0)
        self.report: list[str] = []
        self.stopped = False
        self.respawn_delay = respawn_delay(self.specs)
        self.respawns: dict[str, int] = {}      # node -> times started again
        self.respawn_due: dict[str, float] = {}  # node -> when (time.monotonic) it starts again

    @property
    def node_names(self) -> set[str]:
        return ({spec.name for spec in self.specs} | ({'recorder'} if self.record else set())
                | ({'view'} if self.view is not None else set()))

    def start(self) -> None:
        if self.record is not None:      # parameter files beside the logs
            self.recorder.start('recorder', recorder_spec(self.machine, self.record, self.specs, self.namespace).argv(self.log_dir))
        if self.view is not None:        # a process of its own, also beside a single-process graph
            self.viewer.start_nodes([view_spec(self.machine, self.view, self.namespace)], self.log_dir)
        if self.single_process:
            self.graph.start('graph', single_process_argv(self.specs, self.log_dir))
            return
        self.graph.start_nodes(self.specs, self.log_dir)

    def check(self) -> None:
        """Raise processes.ChildExited when a node process has ended on its own before the
        graph is ready, or when hw_sim (or the one process of a single-process graph) has;
        once ready, any other node's end is a notice and the node starts again when due
        (module docstring). The recorder's end later is a lost recording
        (:meth:`lose_recording`); the view's a notice (nothing of the machine depends on it)."""
        view = self.viewer.children.get('view')
        if view is not None and not view.stopping and not view.running():
            if not self.ready:
                self.viewer.check()
            view.stopping = True
            self.notices.append(f'the live view exited with code {view.returncode} (its log: {view.log_path}); '
                                'the graph keeps running')
        child = self.recorder.children.get('recorder')
        if child is not None and not child.stopping and not child.running():
            if not self.ready:
                self.recorder.check()
            child.stopping = True                   # its end is known now
            self.lose_recording(f'recorder exited with {exit_text(child)}')
        if not self.ready or self.single_process:
            self.graph.check()
            return
        for name, node in list(self.graph.children.items()):
            if not node.stopping and not node.running():
                self._node_ended(name, node)
        now = time.monotonic()
        for name, due in list(self.respawn_due.items()):
            if now >= due:
                del self.respawn_due[name]
                self.respawns[name] = self.respawns.get(name, 0) + 1
                self.graph.start(name, self.graph[name].argv)
                self.notices.append(f'{name} started again ({self.respawns[name]} of {RESPAWN_MAX})')

    def _node_ended(self, name: str, node) -> None:
        """A node process of the ready graph ended on its own: hw_sim's end raises; any other's
        is a notice, and its start again is scheduled where due (module docstring)."""
        if name in NOT_RESPAWNED:
            self.graph.check()                          # raises ChildExited for it
        self.graph.stop(name)                   # what is left of its process group (a planner process)
        ended = f'{name} exited with {exit_text(node)}'
        if node.returncode == 0:
            self.notices.append(f'{ended}: asked to stop from outside, not started again; the graph keeps running')
        elif self.respawns.get(name, 0) >= RESPAWN_MAX:
            self.notices.append(f'{ended}: not started again (started again {RESPAWN_MAX} times already); '
                                'the graph keeps running')
        else:
            self.respawn_due[name] = time.monotonic() + self.respawn_delay
            self.notices.append(f'{ended}; starting it again in {self.respawn_delay:g} s; the graph keeps running '
                                f'(a faulted machine continues with {contract.RESET.name} once it answers)')

    def lose_recording(self, reason: str) -> None:
        """The recording stopped while the graph runs: note it (once) for the shell, or raise
        RecordingLost if the session asked to stop then."""
        if self.recording_lost is not None:
            return
        self.recording_lost = reason
        text = recording_lost_text(reason, self.record)
        if self.stop_on_recording_loss:
            raise RecordingLost(f'{text} (--stop-on-recording-loss: stopping the graph)')
        self.notices.append(f'{text}; the graph keeps running')

    def wait_ready(self, client, timeout: float = READY_TIMEOUT) -> float:
        """Wait until every node is on the ROS graph (in the namespace) and the graph is
        ready (contract.READY); returns the seconds waited."""
        started = time.monotonic()
        namespace = self.namespace or '/'
        client.wait(lambda: self.node_names <= {name for name, ns in client.node.get_node_names_and_namespaces()
                                                if ns == namespace},
                    'every node on the ROS graph', timeout, self.check)
        left = max(timeout - (time.monotonic() - started), 0.0)
        client.wait_ready(left, self.check)
        self.ready = True
        return time.monotonic() - started

    def stop(self) -> list[str]:
        """Stop the graph, then the recorder (drain, close the bag); returns the recorder's
        report lines (per-topic counts) or []. Once only; later calls return the same."""
        if self.stopped:
            return self.report
        self.stopped = True
        self.viewer.stop_all()
        self.graph.stop_all()
        if 'recorder' not in self.recorder.children:
            return []
        child = self.recorder['recorder']
        ended = not child.running()
        self.recorder.stop_all()
        lines = child.tail(200)
        start = max((i for i, line in enumerate(lines) if line.startswith('recorded ')), default=None)
        if start is not None:
            self.report = lines[start:]
        elif ended and self.recording_lost is not None:
            self.report = [recording_lost_text(self.recording_lost, self.record)]
        else:
            self.report = [f'recorder: no report; last output: {lines[-5:]}']
        return self.report

    def __enter__(self) -> Bringup:
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop()


def client_node(name: str, domain_id: int | None = None, namespace: str = ''):
    """An rclpy context + node for a command-line client (rclpy's signal handlers off:
    the shell decides what Ctrl-C does), in `domain_id` (default: ROS_DOMAIN_ID) and in
    the graph's `namespace` (its relative names then resolve to the graph's). Returns
    (context, node)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    context = Context()
    rclpy.init(args=['machine-ctrl'], context=context, domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    return context, rclpy.create_node(name, namespace=namespace or None, context=context)


class StateReporter:
    """Prints each new /trajectory/status state (with motion, progress, fault, refusal)."""

    def __init__(self, client, out=sys.stdout):
        self.client, self.out, self.seen = client, out, 0
        self.last = None
        self.tenths = 0            # progress already shown, in tenths of the motion

    def poll(self) -> None:
        statuses = self.client.statuses[self.seen:]
        self.seen += len(statuses)
        for status in statuses:
            values = {kv.key: kv.value for kv in status.values}
            key = (status.message, values.get('rejected_goals'), values.get('motion'))
            tenths = int(float(values.get('progress') or 0) * 10)
            if key != self.last:
                self.last, self.tenths = key, tenths
                print(describe(status.message, values), file=self.out, flush=True)
            elif status.message in ('running', 'holding') and tenths > self.tenths:
                self.tenths = tenths
                print(f'  {tenths * 10} % (sim time {int(values.get("step") or 0) * self.client.machine.control_period:.2f} s, '
                      f'feed override {values.get("feed_override", "1")})', file=self.out, flush=True)


def describe(state: str, values: dict) -> str:
    """One line for a /trajectory/status."""
    text = f'state {state}'
    if values.get('motion') and state in ('running', 'holding'):      # idle / planning: the last motion is done
        text += f": {values['motion']} (progress {float(values.get('progress', 0)) * 100:.0f} %)"
    if state == 'fault' and values.get('fault'):
        text += f" -- {values['fault']}"
    if values.get('last_rejection') and values.get('rejected_goals', '0') != '0':
        text += f" [refused so far: {values['rejected_goals']}, last: {values['last_rejection']}]"
    return text


def api_table(namespace: str = '') -> str:
    """The command API with the fully qualified names in `namespace`."""
    rows = [(contract.absolute(name, namespace), kind, what) for name, kind, what in API]
    width = max(len(name) for name, _, _ in rows)
    type_width = max(len(kind) for _, kind, _ in rows)
    return '\n'.join(f'  {name:{width}s}  {kind:{type_width}s}  {what}' for name, kind, what in rows)


class Stopped(Exception):
    """SIGTERM (or SIGINT) asked the shell to stop."""


def _raise_stopped(*_):
    raise Stopped


def stop_on_signals() -> dict:
    """SIGINT and SIGTERM raise Stopped in the main thread; returns the previous handlers."""
    return {sig: signal.signal(sig, _raise_stopped) for sig in (signal.SIGINT, signal.SIGTERM)}


@contextlib.contextmanager
def client_session(machine: MachineConfig, name: str, domain_id: int | None = None, namespace: str = ''):
    """A command-line client of the graph (in `namespace`): MachineClient on a context of
    its own, closed, destroyed and shut down on leaving."""
    from machine_ctrl.app.client import MachineClient
    context, node = client_node(name, domain_id, namespace)
    client = MachineClient(node, machine)
    try:
        yield client
    finally:
        client.close()
        node.destroy_node()
        context.try_shutdown()


@contextlib.contextmanager
def monitor(machine: MachineConfig, name: str, domain_id: int | None = None, namespace: str = ''):
    """client_session with SIGINT / SIGTERM raising Stopped meanwhile."""
    previous = stop_on_signals()
    try:
        with client_session(machine, name, domain_id, namespace) as client:
            yield client
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def signals_ignored():
    """While shutting down: a second Ctrl-C must not cut the bag's closing short."""
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class RecorderStatus:
    """The recorder's entries on /diagnostics (it publishes only once its recording has
    stopped: level ERROR, ``recording stopped: <reason>``), heard by the shell's client."""

    def __init__(self, client):
        from diagnostic_msgs.msg import DiagnosticArray

        from machine_ctrl.ros import messages as ros_io
        self.stopped: str | None = None
        client.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS.name, self._on_diagnostics,
                                        ros_io.qos(contract.DIAGNOSTICS_READER_QOS))

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            prefix = 'recording stopped: '
            if status.name == 'recorder' and status.message.startswith(prefix) and self.stopped is None:
                self.stopped = status.message.removeprefix(prefix) + ' (the recorder is still up)'


def run(args, machine: MachineConfig) -> int:
    """The bringup command: start, wait until ready, report states until asked to stop."""
    from machine_ctrl.app.client import Timeout
    status = 0
    namespace = getattr(args, 'namespace', '')
    paced = (getattr(args, 'real_time_factor', None) or 1.0) if getattr(args, 'paced', False) else None
    try:
        with monitor(machine, 'bringup_monitor', namespace=namespace) as client, \
                Bringup(machine, single_process=args.single_process, record=args.record,
                        dual_stage=not args.no_dual_stage, compensation=args.compensation,
                        namespace=namespace, view=getattr(args, 'view', None),
                        belief=getattr(args, 'identified', None) or (), paced=paced,
                        stop_on_recording_loss=bool(getattr(args, 'stop_on_recording_loss', False))) as bringup:
            try:
                print(f'starting {len(bringup.specs)} nodes ({"one process" if args.single_process else "one process each"})'
                      f'{"" if paced is None else f", paced by the wall clock at {paced:g}x real time"}'
                      f'{", recording to " + args.record if args.record else ""}; logs in {bringup.log_dir}', flush=True)
                recorder_status = RecorderStatus(client) if args.record else None
                bringup.start()
                waited = bringup.wait_ready(client)
                print(f'all nodes ready after {waited:.1f} s: {" ".join(sorted(bringup.node_names))}')
                where = f', namespace {namespace}' if namespace else ''
                print(f'commands (ROS_DOMAIN_ID={client.node.context.get_domain_id()}{where}):\n{api_table(namespace)}',
                      flush=True)
                reporter = StateReporter(client)
                while True:
                    bringup.check()
                    if recorder_status is not None and recorder_status.stopped is not None:
                        bringup.lose_recording(recorder_status.stopped)
                    while bringup.notices:
                        print(bringup.notices.pop(0), flush=True)
                    reporter.poll()
                    time.sleep(0.1)
            except Stopped:
                print('stopping ...', flush=True)
            except (ChildExited, Timeout, RecordingLost) as exc:
                print(f'machine-ctrl: bringup: {exc}', file=sys.stderr)
                status = 1
            finally:
                with signals_ignored():
                    for line in bringup.stop():
                        print(line, flush=True)
            if bringup.recording_lost is not None:
                status = status or 1
    except Stopped:
        status = 130
    return status
