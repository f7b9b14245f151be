"""Child-process supervision for node graphs (graph tests, benchmarks, ``bringup``).

Why a supervisor of our own: there is no ``launch`` package in this environment, and the
graph tests must never leave a node running after a failure, because a stray node in the
same ROS domain would answer the next test's messages. So every child runs in its own
process group, and stopping it means escalating on the whole group (SIGINT, wait,
SIGTERM, wait, contract.STACKS_SIGNAL — a node that did not stop prints where it hangs —
SIGKILL) until no live process of the group is left, grandchildren included.

Also here, because the supervisor's children need it and it needs no ROS import: a
machine-wide lease of a ROS domain id (:func:`reserve_ros_domain`) and the environment
that confines a graph to it (:func:`isolated_ros_env`).

Standard library and the contract only; POSIX (process groups, flock). Group membership is read from
/proc on Linux, so zombies (which never get reaped when PID 1 does not reap orphans, as
in some containers) do not count as alive.
"""
from __future__ import annotations

import atexit
import collections
import errno
import fcntl
import itertools
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Mapping, Sequence

from machine_ctrl import contract
from machine_ctrl import shared_memory

DEFAULT_STOP_TIMEOUT = 5.0   # s to wait after SIGINT and again after SIGTERM
KILL_TIMEOUT = 2.0           # s to wait for the group to vanish after SIGKILL
# assumed: 1 s for a node that did not stop to write its stacks (contract.STACKS_SIGNAL:
# faulthandler writes a few KB from its signal handler at once) before SIGKILL
STACKS_WAIT = 1.0            # s
TAIL_LINES = 200             # output lines kept per child for error reports
_POLL = 0.02                 # s between checks while waiting

# Fast DDS on Linux derives UDP ports from the domain id; ids above 101 can collide with
# the ephemeral port range (ROS 2 docs, "The ROS_DOMAIN_ID"). 0 is everybody's default.
ROS_DOMAIN_FIRST = 1
ROS_DOMAIN_LAST = 101


def exit_code_text(returncode: int) -> str:
    """How a process ended, from its exit code: 'code 2', 'code -9 (killed by SIGKILL)'
    (a signal with no name in this Python: 'killed by signal 40')."""
    if returncode >= 0:
        return f'code {returncode}'
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        name = f'signal {-returncode}'
    return f'code {returncode} (killed by {name})'


class ChildExited(RuntimeError):
    """A child that nobody asked to stop has exited; carries its code and last output so
    the failure report shows why (a traceback, a config error) without opening a log."""

    def __init__(self, name: str, returncode: int, tail: Sequence[str]):
        self.name = name
        self.returncode = returncode
        self.tail = list(tail)
        shown = '\n'.join('    ' + line for line in self.tail) or '    (no output)'
        super().__init__(f'child {name!r} exited with {exit_code_text(returncode)}; last output:\n{shown}')


@dataclass(eq=False)
class Child:
    """One supervised process (the leader of its own process group) and its output."""

    name: str
    argv: list[str]
    process: subprocess.Popen
    log_path: Path | None = None
    stopping: bool = False          # set once stop was requested: its exit is then expected
    _lines: collections.deque = field(default_factory=lambda: collections.deque(maxlen=TAIL_LINES))
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _eof: bool = False
    _reader: threading.Thread | None = None
    _count: int = 0                 # lines read so far (the tail keeps the last TAIL_LINES)

    @property
    def pid(self) -> int:
        """Process id of the child, which is also its process group id."""
        return self.process.pid

    @property
    def returncode(self) -> int | None:
        """Exit code (negative: killed by that signal), None while running."""
        return self.process.poll()

    def running(self) -> bool:
        return self.process.poll() is None

    def tail(self, n: int = 20) -> list[str]:
        """The last n lines of output (stdout and stderr interleaved)."""
        with self._cond:
            return list(self._lines)[-n:]

    def group_alive(self) -> bool:
        """Whether any live (non-zombie) process is left in the child's process group; the
        leader is reaped first so that its own zombie does not count."""
        self.process.poll()
        return _group_alive(self.pid)

    def signal_group(self, sig: int) -> None:
        try:
            os.killpg(self.pid, sig)
        except ProcessLookupError:
            pass

    def _pump(self, stream: IO[bytes], log: IO[bytes] | None, echo: IO[str] | None) -> None:
        """Reader thread: keeps the tail, writes the log file, echoes with a name prefix.
        Pipes (not files) so that tails and ``wait_for_line`` work the same in every mode."""
        try:
            for raw in iter(stream.readline, b''):
                line = raw.decode('utf-8', errors='replace').rstrip('\r\n')
                if log is not None:
                    log.write(raw)
                    log.flush()
                if echo is not None:
                    echo.write(f'[{self.name}] {line}\n')
                    echo.flush()
                with self._cond:
                    self._lines.append(line)
                    self._count += 1
                    self._cond.notify_all()
        finally:
            stream.close()
            if log is not None:
                log.close()
            with self._cond:
                self._eof = True
                self._cond.notify_all()


class Supervisor:
    """Starts children in their own process groups and stops them, all of them, in order.

    ``env`` is the complete environment of every child (default: this process's), passed
    through unchanged apart from PYTHONUNBUFFERED=1 (unless set), so that output lines
    arrive when printed. Give it :func:`isolated_ros_env` output to keep a graph in its
    own ROS domain. Output goes to a pipe per child; with ``log_dir`` it is also written
    to ``<log_dir>/<name>.log``, with ``echo`` (e.g. ``sys.stderr``) copied there with a
    ``[name]`` prefix; the last TAIL_LINES lines are always kept for reports.

    Use it as a context manager: leaving the block stops every child, also on an
    exception. An atexit hook does the same for supervisors never closed; nothing can
    help if this process is SIGKILLed.
    """

    def __init__(self, env: Mapping[str, str] | None = None, *, log_dir: str | os.PathLike | None = None,
                 echo: IO[str] | None = None, stop_timeout: float = DEFAULT_STOP_TIMEOUT):
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault('PYTHONUNBUFFERED', '1')
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.echo = echo
        self.stop_timeout = stop_timeout
        self.children: dict[str, Child] = {}
        self._lock = threading.Lock()
        self._atexit = False

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc_info) -> None:
        self.stop_all()

    def __getitem__(self, name: str) -> Child:
        return self.children[name]

    def start(self, name: str, argv: Sequence[str], *, cwd: str | os.PathLike | None = None,
              extra_env: Mapping[str, str] | None = None) -> Child:
        """Start ``argv`` as child ``name`` in a new process group; returns at once (use
        :meth:`wait_for_line` to wait for readiness). A name can be reused once its
        previous child has been stopped (its log is kept: NAME.1.log, NAME.2.log, ... in
        order). Fast DDS port files left empty (a child picking one would never start) and the
        segments of participants that are gone are removed first (machine_ctrl.shared_memory)."""
        for path in shared_memory.clean():
            print(f'supervisor: removed {path}, left by a Fast DDS participant that died', file=sys.stderr)
        with self._lock:
            old = self.children.get(name)
            if old is not None and (old.running() or not old.stopping):
                raise ValueError(f'a child named {name!r} is already supervised')
            log = None
            log_path = None
            if self.log_dir is not None:
                self.log_dir.mkdir(parents=True, exist_ok=True)
                log_path = self.log_dir / f'{name}.log'
                if old is not None and old.log_path == log_path and log_path.exists():
                    _join_reader(old)               # its last lines written
                    log_path.rename(next(earlier for k in itertools.count(1)
                                         if not (earlier := self.log_dir / f'{name}.{k}.log').exists()))
                log = open(log_path, 'wb')
            env = {**self.env, **(extra_env or {})}
            try:
                process = subprocess.Popen(list(argv), env=env, cwd=cwd, stdin=subprocess.DEVNULL,
                                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                           process_group=0, preexec_fn=default_stop_signals)
            except BaseException:
                if log is not None:
                    log.close()
                raise
            child = Child(name, list(argv), process, log_path)
            child._reader = threading.Thread(target=child._pump, args=(process.stdout, log, self.echo),
                                             name=f'supervisor-{name}', daemon=True)
            child._reader.start()
            self.children[name] = child
            if not self._atexit:
                atexit.register(self.stop_all)
                self._atexit = True
            return child

    def alive(self) -> list[str]:
        """Names of the children whose main process is still running, in start order."""
        return [name for name, child in self.children.items() if child.running()]

    def check(self) -> None:
        """Raise :class:`ChildExited` for the first child that has exited although nobody
        asked it to stop (whatever its exit code: a node is not supposed to finish)."""
        for child in self.children.values():
            if not child.stopping and not child.running():
                raise ChildExited(child.name, child.returncode, _final_tail(child))

    def wait_for_line(self, name: str, text: str, timeout: float) -> str:
        """Wait until child ``name`` prints a line containing ``text`` (searched in the
        retained tail, so a line printed before the call counts) and return that line.
        Raises :class:`ChildExited` if the child ends first, TimeoutError after timeout."""
        child = self.children[name]
        deadline = time.monotonic() + timeout
        with child._cond:
            while True:
                for line in child._lines:
                    if text in line:
                        return line
                if child._eof:
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f'child {name!r} printed no line containing {text!r} within '
                                       f'{timeout} s; last output:\n' + '\n'.join(child.tail()))
                child._cond.wait(min(remaining, 0.5))
        try:    # its output ended: normally it is exiting
            child.process.wait(max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            raise TimeoutError(f'child {name!r} closed its output without printing {text!r}') from None
        raise ChildExited(name, child.returncode, _final_tail(child))

    def stacks(self, name: str, timeout: float = STACKS_WAIT) -> list[str]:
        """Every thread's stack of child `name`, the child going on: contract.STACKS_SIGNAL to
        the processes of its group that catch it, then the lines it printed until `timeout`
        passes with no new line ([] when none catches it or it printed nothing). For a
        failure's report: what a node that stopped answering is doing."""
        child = self.children[name]
        with child._cond:
            first = child._count
        if not _signal_catchers(child.pid, contract.STACKS_SIGNAL):
            return []
        with child._cond:
            seen = first
            while child._cond.wait_for(lambda: child._count > seen or child._eof, timeout) and not child._eof:
                seen = child._count
            new = child._count - first
            return list(child._lines)[-new:] if new else []

    def wait(self, name: str, timeout: float | None = None) -> int:
        """Wait for child ``name`` to end by itself and return its exit code (for children
        that are meant to finish, e.g. a recording job). subprocess.TimeoutExpired on
        timeout; the child keeps running then."""
        child = self.children[name]
        code = child.process.wait(timeout)
        child.stopping = True       # it ended as the caller expected
        _join_reader(child)
        return code

    def stop(self, name: str, timeout: float | None = None) -> int | None:
        """Stop child ``name`` and its whole process group; returns its exit code."""
        return self._stop([self.children[name]], timeout)[name]

    def start_nodes(self, specs, params_dir=None) -> None:
        """Start each node spec (machine_ctrl.ros.graph.NodeSpec: `name`, `argv()`) as a child
        of its own; its parameter file goes to `params_dir` (None: a temporary file)."""
        for spec in specs:
            self.start(spec.name, spec.argv(params_dir))

    def stop_all(self, timeout: float | None = None) -> dict[str, int | None]:
        """Stop every child: each signal goes to the groups in reverse start order (the
        last started, usually the one depending on the others, first), and the escalation
        runs for all of them together, so the whole stop takes at most about
        2 * timeout + STACKS_WAIT + KILL_TIMEOUT. Returns the exit codes by name."""
        atexit.unregister(self.stop_all)
        self._atexit = False
        return self._stop(list(reversed(self.children.values())), timeout)

    def _stop(self, children: list[Child], timeout: float | None) -> dict[str, int | None]:
        wait = self.stop_timeout if timeout is None else timeout
        for child in children:
            child.stopping = True
        _escalate(children, [(signal.SIGINT, wait), (signal.SIGTERM, wait), (contract.STACKS_SIGNAL, STACKS_WAIT),
                             (signal.SIGKILL, KILL_TIMEOUT)])
        for child in children:
            try:        # its group is gone, so this reaps at once
                child.process.wait(KILL_TIMEOUT)
            except subprocess.TimeoutExpired:
                pass
            _join_reader(child)
        return {child.name: child.returncode for child in children}


def _escalate(children: list[Child], steps: list[tuple[int, float]]) -> None:
    """Send each signal to the groups still alive and wait for them to vanish, until none
    is left; contract.STACKS_SIGNAL only to the processes that catch it (the step skipped
    when none does). A group that survives SIGKILL (a process in uninterruptible sleep) is
    reported on stderr rather than waited for forever."""
    pending = [child for child in children if child.group_alive()]
    for sig, wait in steps:
        if not pending:
            break
        if sig == contract.STACKS_SIGNAL:       # only to those that report their stacks
            sent = [_signal_catchers(child.pid, sig) for child in pending]
            if not any(sent):
                continue
        else:
            for child in pending:
                child.signal_group(sig)
        deadline = time.monotonic() + wait
        while pending and time.monotonic() < deadline:
            time.sleep(_POLL)
            pending = [child for child in pending if child.group_alive()]
    for child in pending:
        print(f'supervisor: process group {child.pid} ({child.name}) survived SIGKILL', file=sys.stderr)


def _signal_catchers(pgid: int, sig: int) -> bool:
    """Send `sig` to the live processes of group `pgid` that catch it (/proc/<pid>/status
    SigCgt), not to the others, whose default action it would be to end; whether any got it."""
    sent = False
    for pid in _live_group_members(pgid) if os.path.isdir('/proc/self') else ():
        try:
            with open(f'/proc/{pid}/status') as status:
                caught = next(int(line.split()[1], 16) for line in status if line.startswith('SigCgt:'))
            if caught >> (sig - 1) & 1:
                os.kill(pid, sig)
                sent = True
        except (OSError, StopIteration, ValueError):     # gone meanwhile
            pass
    return sent


def _join_reader(child: Child, timeout: float = 1.0) -> None:
    """Let the reader thread take the last output; bounded, because a grandchild (or a
    process that left the group) may hold the pipe open after the child is gone."""
    if child._reader is not None:
        child._reader.join(timeout)


def _final_tail(child: Child) -> list[str]:
    """The tail once the dead child's last output has been read (a traceback is usually
    the last thing written, just before the exit we are reporting). Short wait: a living
    grandchild keeps the pipe open, and what the child wrote is already in it."""
    _join_reader(child, 0.2)
    return child.tail()


def _group_alive(pgid: int) -> bool:
    """Whether a live process is in group ``pgid``. killpg(0) alone would count zombies,
    which stay forever where PID 1 does not reap, so on Linux /proc decides."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    if not os.path.isdir('/proc/self'):
        return True
    return any(True for _ in _live_group_members(pgid))


def default_stop_signals() -> None:
    """In a child, between fork and exec: SIGINT and SIGTERM as the OS gives them. An ignored
    signal stays ignored across exec, and a supervisor's own process may ignore them for a
    while (node_common.spin from its end on, bringup while it closes the bag): its children
    must still stop when they are asked to (and a shell's background job, `cmd &`, starts
    with SIGINT ignored: Python then installs no handler, and a `ros2 launch` child never
    hears its Ctrl-C)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def proc_stats():
    """(pid as text, the bytes of /proc/PID/stat) of every process that is still there (Linux)."""
    for entry in os.scandir('/proc'):
        if not entry.name.isdigit():
            continue
        try:
            with open(f'/proc/{entry.name}/stat', 'rb') as f:
                yield entry.name, f.read()
        except OSError:
            continue


def _live_group_members(pgid: int):
    """pids of non-zombie processes whose process group is ``pgid`` (Linux /proc)."""
    for pid, stat in proc_stats():
        state, pgrp = _state_and_pgrp(stat)
        if pgrp == pgid and (state not in _DEAD or _any_thread_running(pid)):
            yield int(pid)


_DEAD = (b'Z', b'X')


def _state_and_pgrp(stat: bytes) -> tuple[bytes, int]:
    """From /proc/<pid>/stat, "pid (comm) state ppid pgrp ...": comm may hold spaces and
    parentheses, hence the split after the last ')'."""
    fields = stat[stat.rfind(b')') + 2:].split()
    return fields[0], int(fields[2])


def _any_thread_running(pid: str) -> bool:
    """A process whose main thread has exited shows 'Z' while its other threads (DDS
    threads tearing down, say) still run: it is only gone when every thread is."""
    try:
        tids = os.listdir(f'/proc/{pid}/task')
    except OSError:
        return False
    for tid in tids:
        try:
            with open(f'/proc/{pid}/task/{tid}/stat', 'rb') as f:
                if _state_and_pgrp(f.read())[0] not in _DEAD:
                    return True
        except OSError:
            continue
    return False


# ---------------------------------------------------------------------------------------
# ROS domain isolation (no ROS import needed: it is all environment variables)

class DomainLease:
    """An exclusive, machine-wide claim on one ROS domain id, held as an flock on
    ``<tmp>/ros_domain_id.<id>.lock``. The kernel drops the lock when this process dies,
    so a crashed test session never leaves a stale claim."""

    def __init__(self, domain_id: int, path: Path, fd: int):
        self.domain_id = domain_id
        self.path = path
        self._fd: int | None = fd

    def release(self) -> None:
        """Give the id back (the lock file stays; removing it would race with a claimer)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> DomainLease:
        return self

    def __exit__(self, *exc_info) -> None:
        self.release()


def reserve_ros_domain(first: int = ROS_DOMAIN_FIRST, last: int = ROS_DOMAIN_LAST,
                       lock_dir: str | os.PathLike | None = None) -> DomainLease:
    """Claim a ROS domain id in [first, last] that no other cooperating session on this
    machine (pytest, benchmark, bringup of any checkout) holds. The search starts at an
    offset derived from the pid, which also spreads us away from ids that
    non-cooperating users pick by hand. Raises RuntimeError when all are taken."""
    if not 0 <= first <= last:
        raise ValueError(f'bad domain id range {first}..{last}')
    directory = Path(lock_dir if lock_dir is not None else tempfile.gettempdir())
    count = last - first + 1
    offset = os.getpid() % count
    for i in range(count):
        domain_id = first + (offset + i) % count
        path = directory / f'ros_domain_id.{domain_id}.lock'
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                continue
            raise
        return DomainLease(domain_id, path, fd)
    raise RuntimeError(f'every ROS domain id in {first}..{last} is held by another session '
                       f'(lock files {directory}/ros_domain_id.*.lock)')


def isolated_ros_env(domain_id: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment (``base``, default os.environ, plus overrides) that keeps ROS
    traffic in ``domain_id`` and on this host: ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE
    =LOCALHOST, no static peers, no deprecated ROS_LOCALHOST_ONLY (Jazzy warns when both
    are set), and AMENT_PREFIX_PATH defaulting to this interpreter's prefix (where the
    PyPI ROS wheels keep the message definitions)."""
    env = dict(os.environ if base is None else base)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_STATIC_PEERS'] = ''
    env.pop('ROS_LOCALHOST_ONLY', None)
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env
