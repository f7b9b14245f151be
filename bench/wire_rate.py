"""Cost of the lock-step graph's messages in Python: rclpy's typed messages against
machine_ctrl.recording.cdr, for a 9-joint sensor_msgs/JointState and a 500-row reference chunk
(trajectory_msgs/JointTrajectory), each way. "take" is what a subscriber pays for the
bytes (rclpy: deserialize_message; cdr: decode, plus the row parsing the nodes do), "send"
what a publisher pays before rclpy hands the bytes on (rclpy: build the message and
serialize it; cdr: encode). Same process, same run.

    .venv/bin/python bench/wire_rate.py
"""
from __future__ import annotations

import os
import sys
import timeit

import numpy as np


def best_us(function, number: int) -> float:
    return min(timeit.repeat(function, number=number, repeat=5)) / number * 1e6


def typed_chunk(clock, first_step, names, positions, velocities, accelerations):
    """The chunk as rclpy message objects (how the nodes built chunks before machine_ctrl.recording.cdr)."""
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    msg = JointTrajectory()
    msg.header.stamp = clock.stamp(first_step)
    msg.joint_names = list(names)
    for i, (p, v, a) in enumerate(zip(positions, velocities, accelerations)):
        point = JointTrajectoryPoint()
        point.positions, point.velocities, point.accelerations = p.tolist(), v.tolist(), a.tolist()
        point.time_from_start = clock.duration(i)
        msg.points.append(point)
    return msg


def main() -> None:
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    from trajectory_msgs.msg import JointTrajectory

    from machine_ctrl.ros import messages as ros_io
    from machine_ctrl.recording.cdr import ChunkDecoder, JointStateDecoder, JointStateEncoder
    from machine_ctrl.model.config import load_machine

    machine = load_machine()
    axes, clock = machine.axis_names, ros_io.StepClock(machine.control_period)
    values = [0.001 * i for i in range(len(axes))]
    stamp = clock.stamp(12345)
    encoder, decoder = JointStateEncoder(axes), JointStateDecoder()
    data = encoder.encode(stamp.sec, stamp.nanosec, values, values, values)

    def rclpy_send():
        return serialize_message(ros_io.joint_state(stamp, axes, values, values, values))
    rows = np.random.default_rng(0).normal(size=(500, len(axes)))
    chunk = ros_io.trajectory_chunk(clock, 1000, axes, rows, rows, rows)
    chunk_decoder = ChunkDecoder()
    cases = [
        ('JointState, 9 joints: take', lambda: ros_io.select(deserialize_message(data, JointState), 'position', axes),
         lambda: ros_io.select(decoder.decode(data), 'position', axes), 20000),
        ('JointState, 9 joints: send', rclpy_send,
         lambda: encoder.encode(stamp.sec, stamp.nanosec, values, values, values), 20000),
        ('chunk, 500 rows: take', lambda: ros_io.parse_chunk(clock, deserialize_message(chunk, JointTrajectory), axes),
         lambda: ros_io.parse_chunk_bytes(clock, chunk_decoder, chunk, axes), 20),
        ('chunk, 500 rows: send', lambda: serialize_message(typed_chunk(clock, 1000, axes, rows, rows, rows)),
         lambda: ros_io.trajectory_chunk(clock, 1000, axes, rows, rows, rows), 20),
    ]
    print(f'{"message":30s} {"rclpy us":>10s} {"cdr us":>10s} {"ratio":>7s}')
    for label, typed, raw, number in cases:
        a, b = best_us(typed, number), best_us(raw, number)
        print(f'{label:30s} {a:10.1f} {b:10.1f} {a / b:7.1f}')


if __name__ == '__main__':
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    main()
