"""Message conversion and validation shared by the nodes (the ROS edge of the functional
core). The message parsers raise :class:`InvalidMessage` (path_to_cl: ValueError) with a one-line reason; nodes catch it,
report it on /diagnostics and keep running.

Time: control step k of a machine with period T happens at sim time t_k = k*T, carried in
stamps as integer nanoseconds (T is a whole number of nanoseconds), so step <-> stamp is
exact in both directions.
"""
from __future__ import annotations

import functools
import importlib

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, PoseStamped
from nav_msgs.msg import Path
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, JointState
from machine_ctrl.model.numeric import MAX_COORDINATE, all_finite
from trajectory_msgs.msg import JointTrajectory

from machine_ctrl import contract
from machine_ctrl.recording.cdr import ChunkData, ChunkDecoder, NotUniform, encode_chunk
from machine_ctrl.model.errors import InvalidMessage
from machine_ctrl.recording.msgdefs import split_type


def qos(spec: contract.Qos) -> QoSProfile:
    """The rclpy profile of a contract QoS."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth,
                      reliability=ReliabilityPolicy.RELIABLE if spec.reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if spec.transient_local else DurabilityPolicy.VOLATILE)


STEP_QOS = qos(contract.STEP_QOS)
REFERENCE_QOS = qos(contract.REFERENCE_QOS)


class StepClock(contract.StepClock):
    """The contract's step clock, with stamps and durations as builtin_interfaces messages."""

    def stamp(self, step: int) -> Time:
        sec, nanosec = self.split(step)
        return Time(sec=sec, nanosec=nanosec)

    def step(self, stamp: Time) -> int:
        return self.step_at(stamp.sec, stamp.nanosec)

    def duration(self, steps: int) -> Duration:
        sec, nanosec = self.split(steps)
        return Duration(sec=sec, nanosec=nanosec)


def _finite(values, what: str) -> list[float]:
    values = [float(v) for v in values]
    if not all_finite(values):
        raise InvalidMessage(f'{what} holds NaN or inf')
    return values


def accelerometer_message(stamp: Time, axis, reading: float) -> Imu:
    """sensor_msgs/Imu of `axis`'s accelerometer (contract.ACCELEROMETERS): frame_id the link
    the axis moves, linear_acceleration the reading (m/s^2) along the joint axis in that frame;
    no orientation and no angular velocity (covariance element 0 = -1, REP 145), the linear
    acceleration's covariance unknown (zeros). The reader's projection back onto the axis
    (:func:`accelerometer_reading`) gives the reading bit for bit when the joint axis is x, y
    or z of its link (every machine here); an oblique axis only to rounding."""
    msg = Imu()
    msg.header.stamp, msg.header.frame_id = stamp, axis.link
    msg.orientation_covariance[0] = msg.angular_velocity_covariance[0] = -1.0
    a = msg.linear_acceleration
    a.x, a.y, a.z = (reading * d for d in axis.direction)
    return msg


def accelerometer_reading(msg: Imu, axes) -> tuple[str, float]:
    """(axis name, m/s^2 along its joint axis) of an accelerometer message from one of `axes`
    (by frame_id = the axis's link); InvalidMessage when the frame is no such axis's or a
    component is NaN or inf."""
    frame = msg.header.frame_id
    axis = next((a for a in axes if a.link == frame), None)
    if axis is None:
        raise InvalidMessage(f'accelerometer frame_id {frame!r} is not the link of '
                             f'{", ".join(f"{a.name} ({a.link})" for a in axes) or "any axis with one"}')
    a = msg.linear_acceleration
    x, y, z = _finite((a.x, a.y, a.z), 'linear_acceleration')
    return axis.name, x * axis.direction[0] + y * axis.direction[1] + z * axis.direction[2]


def tracker_message(stamp: Time, frame: str, reading) -> PointStamped:
    """geometry_msgs/PointStamped of a tracker reading (contract.TRACKER), m."""
    msg = PointStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.point.x, msg.point.y, msg.point.z = reading
    return msg


def tracker_reading(msg: PointStamped, frame: str) -> tuple[float, float, float]:
    """(x, y, z) of a tracker message; InvalidMessage when its frame is not `frame` or a
    coordinate is NaN, inf or beyond +-MAX_COORDINATE (2 m: beyond every shipped machine's reach)."""
    if msg.header.frame_id != frame:
        raise InvalidMessage(f'tracker frame_id {msg.header.frame_id!r} is not the workpiece frame {frame!r}')
    p = msg.point
    reading = tuple(_finite((p.x, p.y, p.z), 'point'))
    if max(map(abs, reading)) > MAX_COORDINATE:
        raise InvalidMessage(f'tracker point {list(reading)} m is beyond +-{MAX_COORDINATE:g} m of the workpiece origin')
    return reading


def joint_state(stamp: Time, names, position=(), velocity=(), effort=()) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position, msg.velocity, msg.effort = list(position), list(velocity), list(effort)
    return msg


def select(msg, field: str, wanted, allow_nonfinite: bool = False) -> list[float]:
    """Values of `field` for the `wanted` axes, in wanted order, from a JointState (or its
    decoded bytes, cdr.JointStateData); every wanted axis must be present exactly once and
    the field as long as the names."""
    values = getattr(msg, field)
    names = tuple(msg.name)
    if len(values) != len(names):
        raise InvalidMessage(f'{len(names)} names but {len(values)} {field} values')
    picks = _picks(names, tuple(wanted))
    picked = list(values)
    if picks is not None:
        picked = [picked[i] for i in picks]
    if allow_nonfinite or all_finite(picked):
        return picked
    raise InvalidMessage(f'{field} holds NaN or inf')


@functools.lru_cache(maxsize=64)
def _picks(names: tuple[str, ...], wanted: tuple[str, ...]) -> tuple[int, ...] | None:
    """columns() once per pair of name lists (a publisher's names do not change); None when
    they are the same."""
    return None if names == wanted else tuple(columns(names, wanted))


def columns(names, wanted) -> list[int]:
    """Index in `names` of every `wanted` joint; names must be unique and complete."""
    if len(set(names)) != len(names):
        raise InvalidMessage('duplicate joint names')
    index = {n: i for i, n in enumerate(names)}
    missing = [w for w in wanted if w not in index]
    if missing:
        raise InvalidMessage(f'missing joints {", ".join(missing)}')
    return [index[w] for w in wanted]


def trajectory_chunk(clock: StepClock, first_step: int, names, positions, velocities, accelerations) -> bytes:
    """Reference rows first_step, first_step+1, ... as a serialized JointTrajectory on the
    control grid (machine_ctrl.recording.cdr; publishers and bag writers take the bytes as they are)."""
    stamp = clock.stamp(first_step)
    return encode_chunk(stamp.sec, stamp.nanosec, names, positions, velocities, accelerations, clock.period_ns)


def parse_chunk(clock: StepClock, msg: JointTrajectory, wanted):
    """(first_step, positions, velocities, accelerations) for the `wanted` axes. Points must
    be consecutive control steps; velocities/accelerations may be empty (taken as zero)."""
    names = list(msg.joint_names)
    picks = columns(names, wanted)
    if not msg.points:
        raise InvalidMessage('reference chunk has no points')
    first = clock.step(msg.header.stamp)
    zeros = [0.0] * len(names)
    positions, velocities, accelerations = [], [], []
    for i, point in enumerate(msg.points):
        offset = point.time_from_start.sec * contract.NS_PER_SECOND + point.time_from_start.nanosec
        if offset != i * clock.period_ns:
            raise InvalidMessage(f'point {i} is not at consecutive control step {i}')
        rows = []
        for field in ('positions', 'velocities', 'accelerations'):
            values = list(getattr(point, field)) or (zeros if field != 'positions' else [])
            if len(values) != len(names):
                raise InvalidMessage(f'point {i}: {len(values)} {field} for {len(names)} joints')
            rows.append(_finite([values[c] for c in picks], f'point {i} {field}'))
        positions.append(rows[0])
        velocities.append(rows[1])
        accelerations.append(rows[2])
    return first, positions, velocities, accelerations


def parse_chunk_bytes(clock: StepClock, decoder: ChunkDecoder, data: bytes, wanted):
    """parse_chunk of a serialized JointTrajectory: decoded by cdr.ChunkDecoder with array
    operations, or by rclpy when its points differ in layout."""
    try:
        chunk = decoder.decode(data)
    except NotUniform:
        try:
            msg = deserialize_message(data, JointTrajectory)
        except Exception as exc:  # noqa: BLE001 - rclpy raises its RMWError on bad bytes
            raise InvalidMessage(f'not a trajectory_msgs/JointTrajectory: {exc}') from None
        return parse_chunk(clock, msg, wanted)
    return _parse_chunk_data(clock, chunk, wanted)


def _parse_chunk_data(clock: StepClock, chunk: ChunkData, wanted):
    """parse_chunk's checks and result, on a decoded chunk with array operations."""
    names = list(chunk.joint_names)
    picks = columns(names, wanted)
    points = len(chunk.time_from_start)
    if not points:
        raise InvalidMessage('reference chunk has no points')
    first = clock.step_at(chunk.sec, chunk.nanosec)
    off_grid = np.flatnonzero(chunk.time_from_start != np.arange(points) * clock.period_ns)
    if off_grid.size:
        raise InvalidMessage(f'point {off_grid[0]} is not at consecutive control step {off_grid[0]}')
    rows = []
    for field in ('positions', 'velocities', 'accelerations'):
        values = getattr(chunk, field)
        if values.shape[1] == 0 and field != 'positions':
            values = np.zeros((points, len(names)))
        if values.shape[1] != len(names):
            raise InvalidMessage(f'point 0: {values.shape[1]} {field} for {len(names)} joints')
        picked = values[:, picks]
        finite = np.isfinite(picked).all(axis=1)
        if not finite.all():
            raise InvalidMessage(f'point {np.argmin(finite)} {field} holds NaN or inf')
        rows.append(picked.tolist())
    return first, *rows


def quaternion_z_to(axis) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the shortest rotation taking +z onto the unit vector `axis`."""
    o = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    w = 1.0 + o[2]                           # unnormalized: (z x o, 1 + z.o)
    if w < 1e-12:                            # o = -z: half a turn about x
        return (1.0, 0.0, 0.0, 0.0)
    q = np.array([-o[1], o[0], 0.0, w])
    return tuple(float(v) for v in q / np.linalg.norm(q))


def path_message(cl, frame: str) -> Path:
    """nav_msgs/Path of CL data: pose position = tool tip, pose z-axis = tool axis."""
    msg = Path()
    msg.header.frame_id = frame
    for p, o in zip(cl.positions, cl.axes):
        pose = PoseStamped()
        pose.header.frame_id = frame
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in p)
        q = pose.pose.orientation
        q.x, q.y, q.z, q.w = quaternion_z_to(o)
        msg.poses.append(pose)
    return msg


def path_to_cl(msg: Path, frame: str):
    """CL data (trajectory.toolpath.CLData: tool tips in m, unit tool axes) of a nav_msgs/Path
    in the workpiece frame `frame`: pose position = tool tip, pose z-axis = tool axis.
    ValueError naming the first problem and its pose: a frame, a quaternion that is not
    finite or not unit (toolpath.QUATERNION_TOLERANCE, tf2's), too few poses, a position
    that is not finite, repeated positions (toolpath.CLData). Whether the machine can reach
    the poses is the planner's question (trajectory.reach)."""
    from trajectory import toolpath
    if msg.header.frame_id != frame:
        raise ValueError(f'frame_id {msg.header.frame_id!r} is not the workpiece frame {frame!r}')
    bad = [i for i, p in enumerate(msg.poses) if p.header.frame_id not in ('', frame)]
    if bad:
        raise ValueError(f'pose {bad[0]}: frame_id {msg.poses[bad[0]].header.frame_id!r} is not {frame!r}')
    if not msg.poses:
        raise ValueError('path has no poses')
    p = np.array([(q.pose.position.x, q.pose.position.y, q.pose.position.z) for q in msg.poses])
    o = np.array([(q.pose.orientation.x, q.pose.orientation.y, q.pose.orientation.z, q.pose.orientation.w)
                  for q in msg.poses])
    return toolpath.from_arrays(p, toolpath.axes_from_quaternions(o))


def pose_message(stamp: Time, frame: str, pose) -> PoseStamped:
    """geometry_msgs/PoseStamped of a 4 x 4 homogeneous pose."""
    msg = PoseStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame
    p = msg.pose.position
    p.x, p.y, p.z = (float(v) for v in pose[:3, 3])
    # column-major, as Eigen stores it: eigenpy 3.13 copies a matrix of another layout (a C-order
    # view) into a heap Matrix3d it never frees, 80 bytes a call (hw_sim's ground-truth pose
    # every 10 steps: the soak's 8 bytes per step, bench/pose_message_memory.py)
    q = pin.Quaternion(np.asfortranarray(pose[:3, :3]))
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = float(q.x), float(q.y), float(q.z), float(q.w)
    return msg


def diagnostics(stamp: Time, name: str, level: bytes, message: str, values: dict) -> DiagnosticArray:
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id='machine_ctrl')
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    array = DiagnosticArray()
    array.header.stamp = stamp
    array.status = [status]
    return array


def message_class(type_name: str):
    """The rclpy message class of 'pkg/msg/Type'; LookupError if not importable."""
    package, name = split_type(type_name)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name)
    except (ImportError, AttributeError):
        raise LookupError(f'message type {type_name} is not installed') from None
