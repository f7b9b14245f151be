"""A session seen in Foxglove (issue [7/8], part 3): the graph's messages, decimated, and
what the analysis plots show, on Foxglove channels (foxglove-sdk), ROS-free.

One :class:`SessionView` takes a session's messages as CDR bytes (:meth:`SessionView.take`:
the topic, its type and the serialized message, as a ROS subscription or a bag gives them)
and logs, on the channels of a foxglove Context:

* every topic it is given, under its own name and ROS type (``ros2msg`` schema from the
  ament index, CDR passed through undecoded), so Foxglove's panels decode them as they
  decode a bag. The per-step streams (``contract.PER_STEP_TOPICS`` and the contour errors,
  one message per control step) are decimated to one message every ``ViewConfig.period``
  of sim time: by their header stamp where they have one (a multiple of the period), else
  every n-th message counted from the first (the Float64 magnitudes) — unless the caller
  samples them itself (`sampled`: the view node takes the newest message of each at a wall
  rate, so that the messages it leaves never reach Python). The rest (goal status, trajectory status, diagnostics, reference chunks, the
  URDF) pass whole;
* ``contract.VIEW_TRACKING_ERROR`` (JSON: sim time s, per-axis reference − measured
  position, m or rad, from /reference as ``machine-ctrl analyze``), as ``errors.png``
  (machine_ctrl/recording/plots.py);
* ``contract.VIEW_SCENE`` (foxglove.SceneUpdate, in the machine's workpiece frame, m): the
  commanded tool path (forward kinematics of the /reference rows) and the measured tool-tip
  trace (of the forwarded joint states), the last ``ViewConfig.trace_points`` of each, as
  ``path_xy.png`` in 3D. Both are logged at the log time of the joint state they come from
  (a bag's, or now).

Where the messages go is the Context's sinks: the WebSocket server of ``machine-ctrl view``
(a live graph: machine_ctrl/ros/view_node.py) or an MCAP file (``machine-ctrl view --bag``:
a recorded session with the same channels, so the machine's layout, config/foxglove/<machine>.json
of machine_ctrl/view/layout.py, opens both).
A message the view cannot read (a foreign type, a bad CDR, a state or chunk without the
machine's axes) is not forwarded: ``take`` returns False, its reason in ``skipped`` and
given to ``refused``; the view never raises on what a node sent.
"""
from __future__ import annotations

import collections
import json
from dataclasses import dataclass

import foxglove
import numpy as np
from foxglove.channels import SceneUpdateChannel
from foxglove.messages import Color, LinePrimitive, LinePrimitiveLineType, Point3, SceneEntity, SceneUpdate

from machine_ctrl import contract
from machine_ctrl.model.config import MachineConfig
from machine_ctrl.model.kinematics import Kinematics
from machine_ctrl.recording import cdr, msgdefs
from machine_ctrl.recording.analysis import machine_of
from machine_ctrl.recording.bag import Bag
from machine_ctrl.recording.recorder import namespace_of

# The per-step streams: one message per control step, decimated.
PER_STEP = frozenset(t.name for t in contract.PER_STEP_TOPICS) | frozenset(
    t.name for t in (contract.CONTOUR_TOOL_TIP, contract.CONTOUR_TOOL_TIP_MAGNITUDE, contract.CONTOUR_ORIENTATION,
                     contract.CONTOUR_ORIENTATION_MAGNITUDE))
MAGNITUDES = frozenset((contract.CONTOUR_TOOL_TIP_MAGNITUDE.name, contract.CONTOUR_ORIENTATION_MAGNITUDE.name))
# assumed: 16 joint-name lists (a graph has one or two; more is a publisher varying its names)
COLUMNS_KEPT = 16
_TRACKING_SCHEMA = {'type': 'object', 'properties': {
    'time': {'type': 'number', 'description': 'sim time, s'},
    'error': {'type': 'object', 'description': 'reference - measured position per axis, m or rad',
              'additionalProperties': {'type': 'number'}}}}
# assumed: 64 chunks (32 k steps, the trajectory node's lookahead ten times over): the rows
# of every step a forwarded state can have, a stream re-sent after a hold included
REFERENCE_CHUNKS_KEPT = 64
_PATH_COLOR = Color(r=0.3, g=0.6, b=1.0, a=1.0)
_TRACE_COLOR = Color(r=1.0, g=0.45, b=0.1, a=1.0)


@dataclass(frozen=True)
class ViewConfig:
    """`period`: sim time between two forwarded messages of a per-step stream when the view
    decimates (a bag), and between two points of the commanded path in the scene, s.
    assumed: 0.01 s (100 Hz of sim time: a 10 kHz stream shown every 100th step, what a
    plot panel draws smoothly over a session of minutes). `trace_points`: the scene's path
    and trace keep this many points each. assumed: 5000 (50 s of motion at `period`; a
    scene update of 2 x 5000 points is ~240-290 kB: three float64 each). `scene_every`: a scene update every this
    many forwarded joint states. assumed: 10 (5-10 Hz live, 10 Hz of sim time in a bag)."""
    period: float = 0.01
    trace_points: int = 5000
    scene_every: int = 10

    def __post_init__(self):
        if not (self.period > 0 and np.isfinite(self.period)):
            raise ValueError(f'view period must be a positive number of seconds, got {self.period!r}')
        if self.trace_points < 2 or self.scene_every < 1:
            raise ValueError(f'trace_points must be >= 2 and scene_every >= 1, got {self.trace_points}, '
                             f'{self.scene_every}')


class SessionView:
    """The channels of one session (module docstring). `context`: the foxglove Context whose
    sinks receive the messages; `namespace`: the graph's ('' or '/NS'), stripped from the topic
    names the view recognises (the channels keep the full names)."""

    def __init__(self, machine: MachineConfig, context: foxglove.Context, config: ViewConfig = ViewConfig(),
                 namespace: str = '', sampled: bool = False, refused=None):
        self.machine, self.context, self.config, self.sampled = machine, context, config, sampled
        self.refused = refused or (lambda _topic, _reason: None)
        self.namespace = namespace.rstrip('/')
        self.kinematics = Kinematics.from_config(machine)
        self.clock = contract.StepClock(machine.control_period)
        # steps per forwarded message of a per-step stream
        self.every = max(1, round(config.period / machine.control_period))
        self.channels: dict[str, foxglove.Channel] = {}
        self.counts: collections.Counter = collections.Counter()      # messages taken per topic
        self.forwarded: collections.Counter = collections.Counter()
        self.skipped: dict[str, str] = {}                             # topic -> the last reason
        self.scene = SceneUpdateChannel(contract.VIEW_SCENE, context=context)
        self.tracking = foxglove.Channel(
            contract.VIEW_TRACKING_ERROR, message_encoding='json', context=context,
            schema=foxglove.Schema(name='machine_ctrl/TrackingError', encoding='jsonschema',
                                   data=json.dumps(_TRACKING_SCHEMA).encode()))
        self._states = cdr.JointStateDecoder()
        self._chunks = cdr.ChunkDecoder()
        self._columns: dict[tuple, np.ndarray | None] = {}
        # the recent reference chunks: (first step, rows of the machine's axes)
        self._reference: collections.deque = collections.deque(maxlen=REFERENCE_CHUNKS_KEPT)
        self._path: collections.deque = collections.deque(maxlen=config.trace_points)
        self._trace: collections.deque = collections.deque(maxlen=config.trace_points)
        self._states_forwarded = 0

    def _local(self, topic: str) -> str:
        """The contract's (relative) name of a topic: its namespace and leading / stripped."""
        if self.namespace and topic.startswith(self.namespace + '/'):
            topic = topic[len(self.namespace):]
        return topic.lstrip('/')

    def _channel(self, topic: str, type_name: str, definition: bytes | None) -> foxglove.Channel:
        channel = self.channels.get(topic)
        if channel is None:
            schema = foxglove.Schema(name=type_name, encoding='ros2msg',
                                     data=definition or msgdefs.definition(type_name).encode())
            channel = self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding='cdr',
                                                              context=self.context)
        return channel

    def take(self, topic: str, type_name: str, data: bytes, log_time: int | None = None,
             definition: bytes | None = None) -> bool:
        """One message of `topic` (its CDR bytes): forwarded (True) or left out by the
        decimation or as unreadable (False, the reason in `skipped`). `log_time` (ns): the
        time to log it at (a bag's); default now. `definition`: the type's ros2msg schema
        (a bag's); default from the ament index."""
        self.counts[topic] += 1
        local = self._local(topic)
        try:
            if local in PER_STEP and not self.sampled and not self._due(topic, data):
                return False
            channel = self._channel(topic, type_name, definition)
            if local == contract.JOINT_STATES.name:
                self._joint_state(data, log_time)
            elif local == contract.REFERENCE.name:
                self._chunk(data)
        except (cdr.InvalidMessage, msgdefs.DefinitionNotFound, ValueError) as exc:
            self.skipped[topic] = f'{type(exc).__name__}: {exc}'
            self.refused(topic, self.skipped[topic])
            return False
        channel.log(bytes(data), log_time=log_time)
        self.forwarded[topic] += 1
        return True

    def _due(self, topic: str, data: bytes) -> bool:
        """A per-step message to forward: of a step that is a multiple of `every` (by its
        header's stamp), or every `every`-th (no header: the Float64 magnitudes)."""
        if self._local(topic) in MAGNITUDES:
            return (self.counts[topic] - 1) % self.every == 0
        return self.clock.step_of_ns(cdr.stamp_ns(data)) % self.every == 0

    def _positions(self, names) -> np.ndarray | None:
        """Column of each machine axis in a message's joint names (None: an axis missing)."""
        key = tuple(names)
        if key not in self._columns:
            if len(self._columns) >= COLUMNS_KEPT:
                self._columns.clear()
            index = {name: i for i, name in enumerate(key)}
            self._columns[key] = (np.array([index[a] for a in self.machine.axis_names])
                                  if all(a in index for a in self.machine.axis_names) else None)
        return self._columns[key]

    def _joint_state(self, data: bytes, log_time: int | None) -> None:
        state = self._states.decode(data)
        columns = self._positions(state.name)
        if columns is None or len(state.position) != len(state.name):
            raise ValueError('a joint state without every axis of the machine')
        q = np.asarray(state.position)[columns]
        step = self.clock.step_at(state.sec, state.nanosec)
        self._trace.append(self.kinematics.forward(q)[0])
        row = self._reference_row(step)
        if row is not None:
            error = {name: float(e) for name, e in zip(self.machine.axis_names, row - q)}
            self.tracking.log(json.dumps({'time': contract.seconds(state.sec, state.nanosec), 'error': error}),
                              log_time=log_time)
        self._states_forwarded += 1
        if self._states_forwarded % self.config.scene_every == 0:
            self.scene.log(self.scene_update(state.sec, state.nanosec), log_time=log_time)

    def _chunk(self, data: bytes) -> None:
        chunk = self._chunks.decode(data)
        if not len(chunk.positions):
            return
        columns = self._positions(chunk.joint_names)
        if columns is None or chunk.positions.shape[1] != len(chunk.joint_names):
            raise cdr.InvalidMessage('a reference chunk without a position of every axis of the machine')
        first = self.clock.step_at(chunk.sec, chunk.nanosec)
        rows = chunk.positions[:, columns]
        self._reference.append((first, rows))
        for k in range(-first % self.every, len(rows), self.every):     # the path every `every` steps
            self._path.append(self.kinematics.forward(rows[k])[0])

    def _reference_row(self, step: int) -> np.ndarray | None:
        """The newest reference row of `step` among the chunks kept (None: not there)."""
        for first, rows in reversed(self._reference):
            if first <= step < first + len(rows):
                return rows[step - first]
        return None

    def scene_update(self, sec: int, nanosec: int) -> SceneUpdate:
        """The path and the trace as two line strips in the workpiece frame, stamped (sec, nanosec)."""
        entities = []
        for name, points, color in (('tool_path', self._path, _PATH_COLOR), ('tool_tip', self._trace, _TRACE_COLOR)):
            if len(points) >= 2:
                entities.append(SceneEntity(
                    frame_id=self.machine.workpiece_frame, id=name,
                    timestamp=foxglove.messages.Timestamp(sec=sec, nsec=nanosec),
                    lines=[LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=2.0, scale_invariant=True,
                                         color=color, points=[Point3(x=p[0], y=p[1], z=p[2]) for p in points])]))
        return SceneUpdate(entities=entities)


def view_bag(bag_path, out_path, machine: str | MachineConfig | None = None,
             config: ViewConfig = ViewConfig()) -> SessionView:
    """A recorded session as the live view shows it: every message of the bag at `bag_path`
    through a SessionView into a new MCAP file `out_path` (refused if it exists), the bag's
    log times kept; `machine`: default the one the bag names. Returns the view (its counts).
    BagError / AnalysisError (one line) when the bag cannot be used."""
    context = foxglove.Context()
    with Bag(bag_path) as bag:
        machine = machine_of(bag, machine)
        writer = foxglove.open_mcap(str(out_path), context=context)
        try:
            view = SessionView(machine, context, config, namespace_of(bag.custom_data))
            definitions = {schema.name: schema.data for schema in bag.summary.schemas.values()}
            for message in bag.messages():
                view.take(message.topic, message.type, message.data, message.log_time,
                          definitions.get(message.type))
        finally:
            writer.close()
    return view
