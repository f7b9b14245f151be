"""Recorder throughput: the highest JointState rate (9 axes, as /joint_states carries) that
recorder_node records with zero loss, beside the raw publish rate of the same publisher.

For each target rate the publisher (this process) sends COUNT messages paced at that rate
to one recorder_node (its own process, reliable deep subscription), waits until they are
acknowledged, stops the recorder and compares the recorded count with the published one.
The raw rate is the same publisher sending as fast as it can, in the same run.

    .venv/bin/python bench/recorder_rate.py [COUNT]
"""
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from machine_ctrl.recording.bag import Bag
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain

RATES = (5000, 10000, 20000, 25000, 30000, 35000, 40000, 45000)     # messages/s; 0 below = unpaced


def one_run(supervisor, node, directory, count, rate):
    """(published, recorded, achieved rate) for one paced run."""
    bag = directory / f'bag_{rate}'
    supervisor.start('recorder', [sys.executable, '-m', 'machine_ctrl.ros.recorder_node', '--ros-args',
                                  '-p', f'output:={bag}', '-p', "topics:=['/bench:sensor_msgs/msg/JointState']"])
    supervisor.wait_for_line('recorder', 'recording to', 60)
    publisher = node.create_publisher(JointState, '/bench', QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE))
    while publisher.get_subscription_count() < 1:
        time.sleep(0.02)
    msg = JointState(name=[f'a{i}' for i in range(9)], position=[0.1] * 9, velocity=[0.2] * 9, effort=[0.3] * 9)
    # the first message waits for the recorder's acknowledgement: the publisher's match of
    # the recorder's reader does not mean the reader has matched the publisher yet, and what
    # it sends before that is lost once its 200-deep history has moved on (seen: messages
    # 0-112 of a run at 10,000/s missing, nothing later)
    publisher.publish(msg)
    if not publisher.wait_for_all_acked(Duration(seconds=30)):
        raise SystemExit('the recorder did not acknowledge the first message within 30 s')
    start = time.perf_counter()
    for k in range(1, count):
        if rate:
            ahead = start + (k - 1) / rate - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
        msg.header.stamp.nanosec = k
        publisher.publish(msg)
    elapsed = time.perf_counter() - start
    publisher.wait_for_all_acked(Duration(seconds=30))
    supervisor.stop('recorder')
    node.destroy_publisher(publisher)
    with Bag(bag) as b:
        recorded = b.topics['/bench'].count if '/bench' in b.topics else 0
    return count, recorded, (count - 1) / elapsed


def main(argv) -> int:
    count = int(argv[1]) if len(argv) > 1 else 50_000
    with reserve_ros_domain() as lease, tempfile.TemporaryDirectory() as tmp:
        env = isolated_ros_env(lease.domain_id)
        import os
        os.environ.update(env)
        rclpy.init()
        node = rclpy.create_node('bench_publisher')
        try:
            with Supervisor(env) as supervisor:
                best = raw = 0.0
                print(f'{"target/s":>10s} {"achieved/s":>11s} {"published":>10s} {"recorded":>9s}  loss')
                for rate in (*RATES, 0):
                    published, recorded, achieved = one_run(supervisor, node, Path(tmp), count, rate)
                    lost = published - recorded
                    label = 'raw' if rate == 0 else str(rate)
                    print(f'{label:>10s} {achieved:11.0f} {published:10d} {recorded:9d}  {lost}', flush=True)
                    if rate and lost == 0:
                        best = max(best, achieved)
                    if not rate:
                        raw = achieved
                print(f'zero-loss recorder throughput: {best:.0f} messages/s (highest paced rate without loss), '
                      f'{best / raw:.2f} of the raw publish rate ({raw:.0f}/s)')
        finally:
            node.destroy_node()
            rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main(sys.argv))
