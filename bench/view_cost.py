"""[7/8] part 3: what the live view costs the control loop.

    .venv/bin/python bench/view_cost.py [--machine trt_5axis] [--runs 3] [--seconds 20]

Runs, alternating, `machine-ctrl bringup MACHINE` (a process per node) without and with
`--view 0` (and then a Foxglove WebSocket client subscribed to every channel the view
advertises, reading as fast as it can), each in a ROS domain of its own. Per run, after
the graph is ready: the graph's step rate (hw_sim's step in /trajectory/status, read at the
start and the end of a --seconds wall window; the machine holds its position, every node
steps) and, with the view, the view process's CPU (utime + stime over the window, % of one
core) and the messages the client received. The baseline is the runs without the view, in
the same invocation.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import threading
import time
from pathlib import Path

from machine_ctrl.app.bringup import client_session
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, reserve_ros_domain
from machine_ctrl.model.config import load_machine

TOOL = str(Path(sys.executable).with_name('machine-ctrl'))


def _cpu_seconds(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _view_pid(domain: int) -> int:
    for proc in Path('/proc').iterdir():
        try:
            if b'machine_ctrl.ros.view_node' in (proc / 'cmdline').read_bytes() and \
                    f'ROS_DOMAIN_ID={domain}'.encode() in (proc / 'environ').read_bytes():
                return int(proc.name)
        except (OSError, ValueError):
            continue
    raise RuntimeError('no view process found')


def _client(port: int, stop: threading.Event, counts: dict) -> None:
    """Subscribe to every channel advertised; count the messages until `stop`."""
    from websockets.sync.client import connect
    with connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1'], open_timeout=60) as socket:
        subscribed = set()
        while not stop.is_set():
            try:
                frame = socket.recv(timeout=0.5)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                message = json.loads(frame)
                if message.get('op') == 'advertise':
                    new = [c for c in message['channels'] if c['id'] not in subscribed]
                    subscribed |= {c['id'] for c in new}
                    socket.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                        {'id': c['id'], 'channelId': c['id']} for c in new]}))
            else:
                counts['messages'] = counts.get('messages', 0) + 1
                counts['bytes'] = counts.get('bytes', 0) + len(frame)


def run(machine_name: str, view: bool, seconds: float) -> dict:
    machine = load_machine(machine_name)
    with reserve_ros_domain() as lease, Supervisor(isolated_ros_env(lease.domain_id), stop_timeout=5.0) as sup:
        sup.start('bringup', [TOOL, 'bringup', machine_name] + (['--view', '0'] if view else []))
        logs = Path(sup.wait_for_line('bringup', 'logs in ', timeout=300).rsplit('logs in ', 1)[1].strip())
        sup.wait_for_line('bringup', 'all nodes ready', timeout=300)
        stop, counts, result = threading.Event(), {}, {'view': view}
        reader = None
        if view:
            port = int(re.search(r'ws://127\.0\.0\.1:(\d+)', (logs / 'view.log').read_text()).group(1))
            reader = threading.Thread(target=_client, args=(port, stop, counts), daemon=True)
            reader.start()
            pid = _view_pid(lease.domain_id)
        with client_session(machine, 'view_cost', lease.domain_id) as client:
            def fresh_step() -> tuple[int, float]:
                """The step of the next trajectory status (1 Hz) and when it came."""
                seen = len(client.statuses)
                client.wait(lambda: len(client.statuses) > seen, 'a trajectory status', 60)
                return int(client.status()['step']), time.monotonic()
            fresh_step()
            time.sleep(2.0)                                   # the client subscribed, the view warm
            step0, t0 = fresh_step()
            cpu0, messages0 = _cpu_seconds(pid) if view else 0.0, counts.get('messages', 0)
            time.sleep(seconds)
            step1, t1 = fresh_step()
            cpu1 = _cpu_seconds(pid) if view else 0.0
        stop.set()
        if reader is not None:
            reader.join(5)
        result['steps_per_s'] = (step1 - step0) / (t1 - t0)
        result['real_time_factor'] = result['steps_per_s'] * machine.control_period
        if view:
            result['view_cpu_percent'] = 100 * (cpu1 - cpu0) / (t1 - t0)
            result['client_messages_per_s'] = (counts.get('messages', 0) - messages0) / (t1 - t0)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--machine', default='trt_5axis')
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--seconds', type=float, default=20.0)
    args = parser.parse_args()
    print(f'load average at start: {os.getloadavg()[0]:.2f}')
    results = {False: [], True: []}
    for _ in range(args.runs):
        for view in (False, True):
            r = run(args.machine, view, args.seconds)
            results[view].append(r)
            print(json.dumps(r), flush=True)
    base = statistics.median(r['steps_per_s'] for r in results[False])
    with_view = statistics.median(r['steps_per_s'] for r in results[True])
    print(f'{args.machine}, a process per node, {args.runs} runs each, median steps/s: without the view {base:.0f}, '
          f'with the view and a client {with_view:.0f} ({with_view / base:.2f} of the baseline); view process CPU '
          f'{statistics.median(r["view_cpu_percent"] for r in results[True]):.1f} % of a core; client '
          f'{statistics.median(r["client_messages_per_s"] for r in results[True]):.0f} messages/s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
