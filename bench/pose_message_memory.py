"""[6/8] item 6 (soak): what one ground-truth pose message costs hw_sim's memory.

    .venv/bin/python bench/pose_message_memory.py [--calls 40000]

The soak (bench/soak.py, 2026-12-08) saw hw_sim's RSS grow ~8 bytes per control step: its
ground-truth tool pose (machine_ctrl.ros.messages.pose_message, every 10 steps while the
recorder subscribes) built a pinocchio Quaternion from a C-order 3x3 view of the pose, which
eigenpy 3.13 copies into a heap matrix it never frees. Prints the RSS growth per call of the
same quaternion from that view (the baseline, measured in this run) and of pose_message as it
is now (the rotation passed column-major), for the same poses.
"""
from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time

from machine_ctrl.ros.messages import pose_message


def rss_bytes() -> int:
    with open('/proc/self/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    raise RuntimeError('no VmRSS in /proc/self/status')


def per_call(function, poses) -> float:
    for pose in poses[:1000]:               # warm-up: allocator pools, first-call caches
        function(pose)
    before = rss_bytes()
    for pose in poses:
        function(pose)
    return (rss_bytes() - before) / len(poses)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--calls', type=int, default=40_000)
    args = parser.parse_args()
    rng = np.random.default_rng(0)           # the poses: rotations about random axes, C order (np.eye copies)
    poses = []
    for _ in range(args.calls):
        pose = np.eye(4)
        pose[:3, :3] = pin.exp3(rng.normal(size=3))
        pose[:3, 3] = rng.normal(size=3)
        poses.append(pose)
    stamp = Time(sec=1, nanosec=0)
    baseline = per_call(lambda pose: pin.Quaternion(pose[:3, :3]), poses)
    now = per_call(lambda pose: pose_message(stamp, 'workpiece', pose), poses)
    same = all(np.allclose(pin.Quaternion(pose[:3, :3]).coeffs(),
                           [getattr(pose_message(stamp, 'w', pose).pose.orientation, k) for k in 'xyzw'],
                           rtol=0, atol=0) for pose in poses[:100])
    print(f'{args.calls} calls each; RSS growth per call:')
    print(f'  baseline  pin.Quaternion(C-order view)         {baseline:8.1f} B')
    print(f'  now       pose_message (rotation column-major)  {now:8.1f} B')
    print(f'  same quaternion (first 100, exactly): {same}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
