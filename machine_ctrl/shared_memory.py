"""What Fast DDS leaves in shared memory when a process ends without deleting its participant,
and its removal: ports left empty, and segments of participants that are gone.

**Ports left empty.** 
Fast DDS (the RMW of this project) gives each participant shared-memory ports, files
``/dev/shm/fastrtps_port<N>`` that it creates and then sizes and fills (boost.interprocess
``managed_open_or_create``). A process killed between the two steps leaves the file at 0
bytes, and every later process that picks the same port opens it and waits for the size to
be set, forever: its ``rclpy.init``/first node never returns. Some port numbers do not depend
on the ROS domain (seen 2026-12-06: ``fastrtps_port7004``, 0 bytes, held a test worker of
another domain for 10 min until it was killed; the creator was gone). Such a file is
garbage: nothing can use it, and removing it lets the next participant create the port
afresh. A process already waiting on it stays stuck; so this runs before graphs start
(:class:`machine_ctrl.app.processes.Supervisor`, the test session).

**Segments of participants that are gone.** Each participant writes what it sends over shared
memory into a segment of its own, ``/dev/shm/fastrtps_<16 hex digits>`` (~0.5 MB), and holds
the lock file ``<segment>_el`` flock'ed for its life; deleting the participant removes both,
and so does a node process that ends without deleting it (node_common.end_process). A
process killed leaves them. A segment whose lock file no process holds, older than
:data:`STALE_AFTER`, is garbage: :func:`remove_zombie_segments` (what Fast DDS's own
``fastdds shm clean`` does), run where stale ports are.

Standard library only; Linux (/proc).
"""
from __future__ import annotations

import fcntl
import os
import re
import time
from pathlib import Path

SHM_DIR = Path('/dev/shm')
PORT_FILE = re.compile(r'fastrtps_port\d+')
SEGMENT_LOCK = re.compile(r'fastrtps_[0-9a-f]{16}_el')
# assumed: Fast DDS sizes a port file right after creating it (microseconds apart), holding it
# open in between. One empty this long after its last change, and open in no process when
# looked at after that (remove_stale_ports stats first), was left by a process that died in
# between: a live creator still holds it. Short, because a graph restarting a node it just
# killed starts it within seconds (test_faults' contour_error, killed right after SIGCONT,
# when Fast DDS re-creates its ports, left one that hung its restart; 10 s before 2026-12-07).
STALE_AFTER = 1.0           # s


def open_files(proc: Path = Path('/proc')) -> set[tuple[int, int]]:
    """(device, inode) of every file open in a process this one can see."""
    held = set()
    for fd_dir in proc.glob('[0-9]*/fd'):
        try:
            links = list(fd_dir.iterdir())
        except OSError:                   # gone meanwhile, or not ours to read
            continue
        for link in links:
            try:
                status = link.stat()
            except OSError:
                continue
            held.add((status.st_dev, status.st_ino))
    return held


def empty_ports(directory: Path = SHM_DIR) -> list[tuple[Path, os.stat_result]]:
    """The port files of `directory` that are empty, with their status (an error on one
    file, or on the directory, skips it)."""
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return []
    found = []
    for entry in entries:
        if not PORT_FILE.fullmatch(entry.name):
            continue
        try:
            status = entry.stat()
        except OSError:
            continue
        if status.st_size == 0:
            found.append((Path(entry.path), status))
    return found


def remove_stale_ports(directory: Path = SHM_DIR, now: float | None = None) -> list[Path]:
    """Remove the port files of `directory` that are empty, unchanged for more than
    :data:`STALE_AFTER` s and open in no process; returns the removed paths. Files of other
    names, with content, young or open are left alone; an error on one file skips it."""
    now = time.time() if now is None else now
    candidates = [(path, (status.st_dev, status.st_ino)) for path, status in empty_ports(directory)
                  if now - status.st_mtime > STALE_AFTER]
    if not candidates:
        return []
    held = open_files()
    removed = []
    for path, key in candidates:
        if key in held:
            continue
        try:
            status = path.stat()        # still the same empty file (sized since: in use)
            if status.st_size != 0 or (status.st_dev, status.st_ino) != key:
                continue
            path.unlink()
        except OSError:
            continue
        removed.append(path)
    return removed


def remove_zombie_segments(directory: Path = SHM_DIR, now: float | None = None) -> list[Path]:
    """Remove the participant segments of `directory` whose lock file is older than
    :data:`STALE_AFTER`, open in no process this one can see, and locked by none (an exclusive
    flock of it succeeds: also for processes whose files cannot be seen); returns the removed
    paths (segment, lock file). A creator holds its new lock file open from the moment it
    makes it. Files of other names, young, open or locked ones are left alone; an error on
    one file skips it."""
    now = time.time() if now is None else now
    try:
        candidates = [(Path(e.path), e.stat()) for e in os.scandir(directory) if SEGMENT_LOCK.fullmatch(e.name)]
    except OSError:
        return []
    candidates = [(path, status) for path, status in candidates if now - status.st_mtime > STALE_AFTER]
    if not candidates:
        return []
    held = open_files()
    removed = []
    for lock, status in candidates:
        if (status.st_dev, status.st_ino) in held:
            continue
        try:
            fd = os.open(lock, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            removed += _unlink((segment_of(lock), lock))
        except OSError:                    # locked: its participant lives
            continue
        finally:
            os.close(fd)
    return removed


def segment_of(lock) -> Path:
    """The segment of the lock file ``<segment>_el``."""
    lock = Path(lock)
    return lock.with_name(lock.name[:-len('_el')])


def own_segment_locks() -> list[Path]:
    """The segment lock files this process holds open: its participants'."""
    own = []
    for fd in os.listdir('/proc/self/fd'):
        try:
            target = Path(os.readlink(f'/proc/self/fd/{fd}'))
        except OSError:                    # the listing's own descriptor, closed since
            continue
        if target.parent == SHM_DIR and SEGMENT_LOCK.fullmatch(target.name):
            own.append(target)
    return own


def remove_own_segments() -> list[Path]:
    """Remove this process's participants' segments with their lock files: what deleting the
    participants would remove (node_common.end_process, which ends the process without
    deleting them). Readers that mapped a segment keep their mapping."""
    return _unlink([path for lock in own_segment_locks() for path in (segment_of(lock), lock)])


def _unlink(paths) -> list[Path]:
    """The paths removed (an error on one skips it)."""
    removed = []
    for path in paths:
        try:
            path.unlink()
        except OSError:
            continue
        removed.append(path)
    return removed


def clean(directory: Path = SHM_DIR) -> list[Path]:
    """:func:`remove_stale_ports` and :func:`remove_zombie_segments`: the removed paths."""
    return remove_stale_ports(directory) + remove_zombie_segments(directory)
