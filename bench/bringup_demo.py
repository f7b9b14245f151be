"""[7/7] benchmarks: `machine-ctrl bringup` time to "all nodes ready" (separate processes
and one process), and the demo's wall time with its real-time factor.

    .venv/bin/python bench/bringup_demo.py [--runs 3] [--no-demo]

Each bringup runs in a ROS domain of its own (machine_ctrl.app.processes.reserve_ros_domain);
"ready" is what bringup itself reports (every node on the ROS graph and the trajectory
node streaming), beside the wall time from starting the command to that line (which adds
the command's own imports). The demo is `machine-ctrl demo` as the README runs it; its
phase times and real-time factor are the lines it prints.
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain

TOOL = str(Path(sys.executable).with_name('machine-ctrl'))


def bringup_ready(single_process: bool) -> tuple[float, float]:
    """(bringup's own 'ready after' seconds, wall seconds from the command's start)."""
    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=5.0) as sup:
        start = time.monotonic()
        sup.start('bringup', [TOOL, 'bringup'] + (['--single-process'] if single_process else []))
        line = sup.wait_for_line('bringup', 'all nodes ready after', timeout=300)
        wall = time.monotonic() - start
    return float(re.search(r'after ([0-9.]+) s', line).group(1)), wall


def demo() -> str:
    with tempfile.TemporaryDirectory() as out:
        done = subprocess.run([TOOL, 'demo', '--out', os.path.join(out, 'demo')], capture_output=True, text=True,
                              timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f'demo failed ({done.returncode}): {done.stderr[-2000:]}')
    return '\n'.join(line for line in done.stdout.splitlines() if 'wall time' in line or 'real-time factor' in line)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--no-demo', action='store_true')
    args = parser.parse_args()
    print(f'load average at start: {os.getloadavg()[0]:.2f}')
    for single in (False, True):
        runs = [bringup_ready(single) for _ in range(args.runs)]
        ready = [r[0] for r in runs]
        wall = [r[1] for r in runs]
        print(f'bringup, {"one process" if single else "one process per node"}: all nodes ready after '
              f'{statistics.median(ready):.1f} s median ({", ".join(f"{r:.1f}" for r in ready)}); '
              f'{statistics.median(wall):.1f} s from the command start')
    if not args.no_demo:
        print(demo())
    print(f'load average at end: {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
