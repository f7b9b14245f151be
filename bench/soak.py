"""[6/8] item 6, soak: repeated tool paths on a recorded bringup; RSS and open file
descriptors of every process of the graph must stay flat.

    nice -n 10 .venv/bin/python bench/soak.py [--minutes 30] [--paths circle_xy,helix]
                                              [--warmup-goals 3] [--warmup-minutes 2] [--window 4]

Starts ``machine-ctrl bringup MACHINE --record DIR`` (a process per node, the recorder in
its own) in a ROS domain of its own (machine_ctrl.app.processes.reserve_ros_domain;
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST), then sends the paths in turn with ``machine-ctrl
send`` (a new client process per goal, as an operator or another program would) until
--minutes have passed since the graph was ready; every goal must succeed. Meanwhile, every
--sample-period s, it reads VmRSS, Threads (/proc/PID/status) and the number of open file
descriptors (/proc/PID/fd) of every process of the graph: bringup itself and its
descendants (each node by its ``__node:=`` remapping, the recorder), found once the graph
is ready, with no psutil.

Warm-up (the baseline, measured in the same run): the graph is warm once --warmup-goals
goals have succeeded AND --warmup-minutes have passed since it was ready, whichever comes
later. A process's "RSS after warm-up" is its largest RSS over the --window minutes that
follow; "RSS at end" is its largest RSS over the last --window minutes of the run (a window
spans at least one cycle of the paths, so a planning buffer or a send client in flight
counts in both; at the load of 2026-11-25 a circle_xy + helix cycle took ~4 min). Growth = end / warm-up - 1. FDs are compared the same way (largest count
in each window). The trend column is the least-squares slope of RSS over every sample
after warm-up, in % of the warm-up RSS per 10 minutes.

Criteria (exit status 1 if one fails): RSS growth < 5 % for every process; no FD growth
(end <= warm-up); every goal succeeded; no process of the graph died or appeared; bringup
stopped cleanly and left no process; the bag reads back (every message, through
machine_ctrl.recording.bag.Bag, the counts equal the summary's). A goal that failed because
the machine faulted (on a loaded machine: a node starved past hw_sim's command_timeout)
is followed by /hw_sim/reset, and one whose client timed out by /trajectory/stop, so the
measurement goes on; the run still fails, and stops after 3 failed goals in a row. Ctrl-C / SIGTERM stop
everything (the Supervisor's escalation on every process group) and print what was
measured so far.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from machine_ctrl import contract
from machine_ctrl.app.processes import Supervisor, isolated_ros_env, proc_stats, reserve_ros_domain

TOOL = str(Path(sys.executable).with_name('machine-ctrl'))
RSS_LIMIT = 0.05            # growth after warm-up that fails the soak
READY_TIMEOUT = 300.0       # s for bringup to report every node ready (2 busy cores)
STOP_TIMEOUT = 120.0        # s bringup may take after SIGINT (the recorder drains and closes the bag)


class Interrupted(Exception):
    """SIGINT / SIGTERM: stop everything, report what was measured."""


def _interrupt(*_):
    raise Interrupted


# ---------------------------------------------------------------------------------------
# /proc reading

def _ppid_map() -> dict[int, int]:
    parents = {}
    for pid, stat in proc_stats():
        fields = stat[stat.rfind(b')') + 2:].split()
        if fields[0] not in (b'Z', b'X'):
            parents[int(pid)] = int(fields[1])
    return parents


def descendants(pid: int) -> list[int]:
    parents = _ppid_map()
    children: dict[int, list[int]] = {}
    for child, parent in parents.items():
        children.setdefault(parent, []).append(child)
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def process_name(pid: int, parent: str = '') -> str:
    """The node name (``-r __node:=NAME``); a multiprocessing helper of a node (the
    trajectory node's planner pool: its spawn worker and resource tracker) as
    ``NODE/planner`` and ``NODE/resource_tracker``; else the command's module / program."""
    try:
        with open(f'/proc/{pid}/cmdline', 'rb') as f:
            argv = [a.decode(errors='replace') for a in f.read().split(b'\0') if a]
    except OSError:
        return f'pid {pid}'
    for arg in argv:
        if arg.startswith('__node:='):
            return arg.removeprefix('__node:=')
    text = ' '.join(argv)
    if 'multiprocessing.spawn' in text:
        return f'{parent}/planner'
    if 'multiprocessing.resource_tracker' in text:
        return f'{parent}/resource_tracker'
    if '-m' in argv[:-1]:
        return argv[argv.index('-m') + 1]
    return ' '.join(Path(a).name for a in argv[:3])


@dataclass
class Sample:
    t: float            # s since the graph was ready
    goals: int          # goals succeeded so far
    rss: int            # kB
    fds: int
    threads: int


def read_proc(pid: int) -> tuple[int, int, int] | None:
    """(VmRSS kB, open fds, threads), None when the process is gone (or a zombie)."""
    try:
        with open(f'/proc/{pid}/status') as f:
            status = f.read()
        fds = len(os.listdir(f'/proc/{pid}/fd'))
    except (FileNotFoundError, ProcessLookupError):
        return None
    state = re.search(r'^State:\s+(\S)', status, re.M).group(1)
    rss = re.search(r'^VmRSS:\s+(\d+) kB', status, re.M)
    if state in 'ZX' or rss is None:
        return None
    return int(rss.group(1)), fds, int(re.search(r'^Threads:\s+(\d+)', status, re.M).group(1))


@dataclass
class Watched:
    name: str
    pid: int
    samples: list[Sample] = field(default_factory=list)
    died_at: float | None = None


# ---------------------------------------------------------------------------------------
# the run

@dataclass
class Run:
    minutes: float
    paths: list[str]
    warmup_goals: int
    warmup_minutes: float
    window: float
    watched: list[Watched] = field(default_factory=list)
    goals_ok: int = 0
    goals_failed: list[str] = field(default_factory=list)
    goal_seconds: list[float] = field(default_factory=list)
    ready_after: float | None = None
    warm_at: float | None = None        # s since ready when the warm-up ended
    end_at: float | None = None
    extra_processes: set[str] = field(default_factory=set)
    interrupted: bool = False
    stop_code: int | None = None
    recorder_report: list[str] = field(default_factory=list)
    leftovers: list[str] = field(default_factory=list)
    bag: dict = field(default_factory=dict)
    load: list[tuple[float, float]] = field(default_factory=list)     # (t, 1-min load average)
    resets: list[str] = field(default_factory=list)


def sample_all(run: Run, t: float, root: int) -> None:
    for w in run.watched:
        if w.died_at is not None:
            continue
        values = read_proc(w.pid)
        if values is None:
            w.died_at = t
            print(f'soak: {w.name} (pid {w.pid}) is gone at {t:.0f} s', file=sys.stderr, flush=True)
            continue
        w.samples.append(Sample(t, run.goals_ok, *values))
    known = {w.pid for w in run.watched}
    for pid in descendants(root):
        if pid not in known:        # a process that was not there at ready (a respawned planner, say)
            run.extra_processes.add(f'{process_name(pid)} (pid {pid})')
    run.load.append((t, os.getloadavg()[0]))


def soak(args, run: Run, sup: Supervisor, bag_dir: Path) -> None:
    machine_args = [args.machine]
    start = time.monotonic()
    sup.start('bringup', [TOOL, 'bringup', *machine_args, '--record', str(bag_dir)])
    line = sup.wait_for_line('bringup', 'all nodes ready after', timeout=READY_TIMEOUT)
    run.ready_after = time.monotonic() - start
    ready = time.monotonic()
    root = sup['bringup'].pid
    run.watched = [Watched('bringup', root)]
    names = {root: 'bringup'}
    parents = _ppid_map()
    for pid in sorted(descendants(root)):
        names[pid] = process_name(pid, names.get(parents.get(pid), ''))
        run.watched.append(Watched(names[pid], pid))
    print(f'soak: {line.strip()}', file=sys.stderr)
    print('soak: watching ' + ', '.join(f'{w.name} ({w.pid})' for w in run.watched), file=sys.stderr, flush=True)
    deadline = ready + args.minutes * 60
    next_sample = ready
    next_report = ready + 60
    n = 0
    sending: str | None = None
    sent_at = 0.0
    consecutive_failures = 0
    while True:
        now = time.monotonic()
        t = now - ready
        if now >= next_sample:
            sample_all(run, t, root)
            next_sample += args.sample_period
            if run.warm_at is None and run.goals_ok >= args.warmup_goals and t >= args.warmup_minutes * 60:
                run.warm_at = t
                print(f'soak: warm-up over at {t:.0f} s ({run.goals_ok} goals)', file=sys.stderr, flush=True)
        if any(w.died_at is not None for w in run.watched):
            break
        if sup['bringup'].returncode is not None:
            break
        if sending is not None and not sup[sending].running():
            code = sup.wait(sending)
            seconds = now - sent_at
            tail = sup[sending].tail(5)
            if code == 0:
                run.goals_ok += 1
                run.goal_seconds.append(seconds)
                consecutive_failures = 0
            else:
                run.goals_failed.append(f'goal {n} ({run.paths[(n - 1) % len(run.paths)]}): exit {code}: '
                                        + ' | '.join(tail))
                consecutive_failures += 1
                print(f'soak: {run.goals_failed[-1]}', file=sys.stderr, flush=True)
                # recover so the measurement goes on: a goal the client gave up on (timed out)
                # is stopped, a faulted machine reset; the failed goal still fails the run
                service = (contract.STOP.name if tail and 'timed out' in tail[-1]
                           else contract.RESET.name if tail and 'fault' in tail[-1] else None)
                if service is not None:
                    run.resets.append(f'{service} after goal {n}: ' + call_service(sup, args.machine, service))
                    print(f'soak: {run.resets[-1]}', file=sys.stderr, flush=True)
            sending = None
            if consecutive_failures >= 3:
                print('soak: 3 goals in a row failed; stopping', file=sys.stderr, flush=True)
                break
        if sending is None:
            if now >= deadline:
                break
            path = run.paths[n % len(run.paths)]
            n += 1
            sending = f'send{n}'
            sent_at = now
            sup.start(sending, [TOOL, 'send', path, '--machine', args.machine, '--timeout', str(args.goal_timeout)])
        if now >= next_report:
            next_report += 60
            rss = ' '.join(f'{w.name}={w.samples[-1].rss / 1024:.0f}' for w in run.watched if w.samples)
            print(f'soak: {t / 60:.0f} min, {run.goals_ok} goals, load {os.getloadavg()[0]:.1f}, RSS MB {rss}',
                  file=sys.stderr, flush=True)
        time.sleep(0.2)
    run.end_at = time.monotonic() - ready
    sample_all(run, run.end_at, root)


CALL = """
import sys
from machine_ctrl.app.bringup import client_session
from machine_ctrl.model.config import load_machine
with client_session(load_machine(sys.argv[1]), 'soak_recover') as client:
    client.wait_ready(30)
    print(*client.call(sys.argv[2]))
"""


def call_service(sup: Supervisor, machine: str, service: str) -> str:
    """Call a Trigger service of the graph from a client process of its own: /hw_sim/reset
    for a faulted machine (e.g. a node starved past command_timeout on a loaded machine),
    /trajectory/stop for a goal still running when its client timed out."""
    name = f'call{len(sup.children)}'
    sup.start(name, [sys.executable, '-c', CALL, machine, service])
    try:
        code = sup.wait(name, timeout=60)
    except Exception as exc:        # noqa: BLE001 - reported, the loop decides
        sup.stop(name)
        return f'failed ({exc})'
    return f'exit {code}: ' + ' | '.join(sup[name].tail(2))


def stop_and_check(run: Run, sup: Supervisor) -> None:
    """Stop bringup (SIGINT: graph, then the recorder closes the bag), then look for any
    process of the graph still alive."""
    if 'bringup' not in sup.children:
        return
    pids = {w.pid: w.name for w in run.watched}
    child = sup['bringup']
    run.stop_code = sup.stop_all()['bringup']
    lines = child.tail(200)
    first = max((i for i, text in enumerate(lines) if text.startswith('recorded ')), default=None)
    run.recorder_report = lines[first:] if first is not None else lines[-5:]
    for pid, name in pids.items():
        if read_proc(pid) is not None:
            run.leftovers.append(f'{name} (pid {pid})')


def check_bag(run: Run, bag_dir: Path, machine_name: str) -> None:
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from machine_ctrl.model.config import load_machine
    from machine_ctrl.recording.bag import Bag, BagError
    run.bag['bytes'] = sum(p.stat().st_size for p in bag_dir.rglob('*') if p.is_file())
    started = time.monotonic()
    try:
        with Bag(bag_dir) as bag:
            summary = {name: info.count for name, info in bag.topics.items()}
            read: dict[str, int] = {}
            last_state = None
            for message in bag.messages():
                read[message.topic] = read.get(message.topic, 0) + 1
                if message.topic == '/joint_states':
                    last_state = message.data
    except BagError as exc:
        run.bag['error'] = str(exc)
        return
    run.bag['read_seconds'] = time.monotonic() - started
    run.bag['messages'] = sum(read.values())
    run.bag['summary_messages'] = sum(summary.values())
    run.bag['mismatch'] = {t: (summary.get(t, 0), read.get(t, 0)) for t in set(summary) | set(read)
                           if summary.get(t, 0) != read.get(t, 0)}
    if last_state is not None:
        stamp = deserialize_message(last_state, JointState).header.stamp
        period = load_machine(machine_name).control_period
        run.bag['steps'] = round((stamp.sec + stamp.nanosec * 1e-9) / period)
        run.bag['sim_seconds'] = stamp.sec + stamp.nanosec * 1e-9


# ---------------------------------------------------------------------------------------
# the report

def _window(samples: list[Sample], lo: float, hi: float) -> list[Sample]:
    return [s for s in samples if lo <= s.t <= hi]


def _slope(samples: list[Sample]) -> float:
    """Least-squares RSS slope, kB per s."""
    if len(samples) < 3:
        return 0.0
    mt = statistics.fmean(s.t for s in samples)
    mr = statistics.fmean(s.rss for s in samples)
    den = sum((s.t - mt) ** 2 for s in samples)
    return sum((s.t - mt) * (s.rss - mr) for s in samples) / den if den else 0.0


def report(run: Run, args) -> int:
    failures: list[str] = []
    print(f'\nsoak: {args.machine}, bringup --record (a process per node), paths {",".join(run.paths)} sent in '
          f'turn by machine-ctrl send; {args.minutes:g} min asked')
    if run.ready_after is not None:
        print(f'graph ready after {run.ready_after:.1f} s (from the command start); ran {(run.end_at or 0) / 60:.1f} min '
              f'after that{" (interrupted)" if run.interrupted else ""}')
    if run.load:
        loads = [v for _, v in run.load]
        print(f'load average (1 min) during the run: median {statistics.median(loads):.2f}, '
              f'min {min(loads):.2f}, max {max(loads):.2f} on {os.cpu_count()} cores')
    goals = len(run.goal_seconds)
    if goals:
        print(f'goals: {run.goals_ok} succeeded, {len(run.goals_failed)} failed; wall time per goal (send process '
              f'start to exit) median {statistics.median(run.goal_seconds):.1f} s, '
              f'max {max(run.goal_seconds):.1f} s')
    else:
        print(f'goals: {run.goals_ok} succeeded, {len(run.goals_failed)} failed')
    for text in run.goals_failed:
        print(f'  FAILED {text}')
    for text in run.resets:
        print(f'  reset {text}')
    if run.goals_failed:
        failures.append(f'{len(run.goals_failed)} goal(s) failed')
    if run.goals_ok == 0:
        failures.append('no goal succeeded')
    warm = run.warm_at
    end = run.end_at or 0.0
    window = args.window * 60
    if warm is None:
        print(f'warm-up never ended ({args.warmup_goals} goals and {args.warmup_minutes:g} min); no growth figures')
        failures.append('the run ended before the warm-up was over')
    else:
        if warm + window > end - window:
            print(f'note: the run after warm-up ({(end - warm) / 60:.1f} min) is shorter than two windows: '
                  f'the windows overlap')
        print(f'warm-up: over at {warm / 60:.1f} min after ready ({args.warmup_goals} goals and '
              f'{args.warmup_minutes:g} min, the later); "after warm-up" = largest value in '
              f'[{warm / 60:.1f}, {(warm + window) / 60:.1f}] min, "at end" = largest in '
              f'[{(end - window) / 60:.1f}, {end / 60:.1f}] min; trend = RSS slope after warm-up, % per 10 min')
        print(f'samples every {args.sample_period:g} s')
        print()
        print('| process | pid | RSS after warm-up (MB) | RSS at end (MB) | growth | trend / 10 min | max RSS (MB) '
              '| FDs after warm-up | FDs at end | threads |')
        print('|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|')
        for w in run.watched:
            base = _window(w.samples, warm, warm + window)
            last = _window(w.samples, end - window, end)
            if not base or not last:
                print(f'| {w.name} | {w.pid} | no samples | | | | | | | |')
                failures.append(f'{w.name}: no samples in a window')
                continue
            rss0, rss1 = max(s.rss for s in base), max(s.rss for s in last)
            fd0, fd1 = max(s.fds for s in base), max(s.fds for s in last)
            th0, th1 = max(s.threads for s in base), max(s.threads for s in last)
            growth = rss1 / rss0 - 1
            after = [s for s in w.samples if s.t >= warm]
            trend = _slope(after) * 600 / rss0
            peak = max(s.rss for s in w.samples)
            flag_rss = ' **FAIL**' if growth >= RSS_LIMIT else ''
            flag_fd = ' **FAIL**' if fd1 > fd0 else ''
            print(f'| {w.name} | {w.pid} | {rss0 / 1024:.1f} | {rss1 / 1024:.1f} | {growth * 100:+.1f} %{flag_rss} | '
                  f'{trend * 100:+.2f} % | {peak / 1024:.1f} | {fd0} | {fd1}{flag_fd} | '
                  f'{th0}{"" if th1 == th0 else f" -> {th1}"} |')
            if growth >= RSS_LIMIT:
                failures.append(f'{w.name}: RSS grew {growth * 100:.1f} % after warm-up')
            if fd1 > fd0:
                failures.append(f'{w.name}: open file descriptors {fd0} -> {fd1}')
    print()
    for w in run.watched:
        if w.died_at is not None:
            failures.append(f'{w.name} (pid {w.pid}) died at {w.died_at:.0f} s')
    if run.extra_processes:
        failures.append('processes appeared under bringup after ready: ' + ', '.join(sorted(run.extra_processes)))
    print(f'bringup stopped with exit code {run.stop_code}; recorder: ' + ' / '.join(run.recorder_report))
    if run.stop_code not in (0, 130):
        failures.append(f'bringup exit code {run.stop_code}')
    if run.leftovers:
        failures.append('left running after the stop: ' + ', '.join(run.leftovers))
    else:
        print('after the stop: no process of the graph left')
    bag = run.bag
    if 'error' in bag:
        failures.append(f'the bag does not read back: {bag["error"]}')
    elif bag:
        print(f'bag: {bag["bytes"] / 1e6:.1f} MB; read back with machine_ctrl.recording.bag.Bag in '
              f'{bag["read_seconds"]:.0f} s: {bag["messages"]:,} messages (summary: {bag["summary_messages"]:,})'
              + (f'; last /joint_states at step {bag["steps"]:,} ({bag["sim_seconds"]:.1f} s machine time)'
                 if 'steps' in bag else ''))
        if bag['mismatch']:
            failures.append(f'bag counts differ from its summary: {bag["mismatch"]}')
    if run.interrupted:
        failures.append('interrupted')
    print('verdict: ' + ('PASS' if not failures else 'FAIL: ' + '; '.join(failures)))
    return 1 if failures else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--machine', default='micromill_9axis')
    parser.add_argument('--minutes', type=float, default=30.0, help='sending goals for this long after ready')
    parser.add_argument('--paths', default='circle_xy,helix', help='built-in toolpaths, sent in turn')
    parser.add_argument('--warmup-goals', type=int, default=3)
    parser.add_argument('--warmup-minutes', type=float, default=2.0)
    parser.add_argument('--window', type=float, default=4.0, help='minutes; the baseline and end windows')
    parser.add_argument('--sample-period', type=float, default=5.0, help='s between /proc samples')
    parser.add_argument('--goal-timeout', type=float, default=900.0, help='s (wall) per goal')
    parser.add_argument('--out', help='keep the bag, the logs and samples.csv here (default: a temporary '
                                      'directory, removed)')
    args = parser.parse_args()
    run = Run(args.minutes, args.paths.split(','), args.warmup_goals, args.warmup_minutes, args.window)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix='machine_ctrl_soak_'))
    out.mkdir(parents=True, exist_ok=True)
    bag_dir = out / 'bag'
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    print(f'soak: output in {out}; load average at start {os.getloadavg()[0]:.2f}', file=sys.stderr, flush=True)
    try:
        with reserve_ros_domain() as lease:
            print(f'soak: ROS_DOMAIN_ID={lease.domain_id}', file=sys.stderr, flush=True)
            sup = Supervisor(isolated_ros_env(lease.domain_id), log_dir=out / 'logs', stop_timeout=STOP_TIMEOUT)
            try:
                soak(args, run, sup, bag_dir)
            except Interrupted:
                run.interrupted = True
                print('soak: interrupted; stopping', file=sys.stderr, flush=True)
            finally:
                for sig in previous:        # a second Ctrl-C must not cut the bag's closing short
                    signal.signal(sig, signal.SIG_IGN)
                stop_and_check(run, sup)
                sup.stop_all()
        if bag_dir.exists():
            check_bag(run, bag_dir, args.machine)
        write_samples(run, out / 'samples.csv')
        return report(run, args)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if not args.out:
            shutil.rmtree(out, ignore_errors=True)


def write_samples(run: Run, path: Path) -> None:
    with open(path, 'w') as f:
        f.write('process,pid,t_s,goals,rss_kb,fds,threads\n')
        for w in run.watched:
            for s in w.samples:
                f.write(f'{w.name},{w.pid},{s.t:.1f},{s.goals},{s.rss},{s.fds},{s.threads}\n')


if __name__ == '__main__':
    raise SystemExit(main())
