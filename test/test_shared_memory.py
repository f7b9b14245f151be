"""machine_ctrl.shared_memory: an empty Fast DDS port file, and a participant segment whose lock
file no process holds, unchanged for longer than STALE_AFTER, are removed; every other file
stays. Real files in a temporary directory, this process holding some of them open. The
cleanups are called at the young files' own time (`now`), so that a slow machine does not
age them."""
import os
import time

from machine_ctrl import shared_memory


def aged(path, seconds):
    then = time.time() - seconds
    os.utime(path, (then, then))
    return path


def test_only_empty_old_unheld_port_files_are_removed(tmp_path):
    old = shared_memory.STALE_AFTER + 5
    stale = tmp_path / 'fastrtps_port7004'
    stale.touch()
    aged(stale, old)
    files = {
        'young': tmp_path / 'fastrtps_port7006',               # being created right now, maybe
        'sized': tmp_path / 'fastrtps_port7008',               # a port in use
        'other name': tmp_path / 'fastrtps_7004',              # a participant's, not a port
        'mutex': tmp_path / 'sem.fastrtps_port7004_mutex',
        'held': tmp_path / 'fastrtps_port7010',                # empty and old, but open
    }
    for path in files.values():
        path.touch()
    files['sized'].write_bytes(b'\0' * 64)
    for name in ('sized', 'other name', 'mutex', 'held'):
        aged(files[name], old)
    with open(files['held'], 'rb'):
        removed = shared_memory.remove_stale_ports(tmp_path, now=files['young'].stat().st_mtime)
    assert removed == [stale]
    assert not stale.exists()
    assert all(path.exists() for path in files.values())


def test_a_port_sized_while_the_processes_are_looked_at_stays(tmp_path, monkeypatch):
    """A creator that sizes its port after the file was found empty and old, before its open
    files were looked at (its fd closed by then): the port is in use, and stays."""
    port = tmp_path / 'fastrtps_port7012'
    port.touch()
    aged(port, shared_memory.STALE_AFTER + 5)
    scan = shared_memory.open_files

    def sized_meanwhile():
        port.write_bytes(b'\0' * 64)
        return scan()
    monkeypatch.setattr(shared_memory, 'open_files', sized_meanwhile)
    assert shared_memory.remove_stale_ports(tmp_path) == []
    assert port.stat().st_size == 64


def test_a_missing_directory_removes_nothing(tmp_path):
    assert shared_memory.remove_stale_ports(tmp_path / 'absent') == []


def test_open_files_sees_a_file_this_process_holds(tmp_path):
    path = tmp_path / 'x'
    path.touch()
    status = path.stat()
    with open(path, 'rb'):
        assert (status.st_dev, status.st_ino) in shared_memory.open_files()
    assert (status.st_dev, status.st_ino) not in shared_memory.open_files()


def test_only_old_participant_segments_whose_lock_no_process_holds_are_removed(tmp_path):
    import fcntl
    old = shared_memory.STALE_AFTER + 5
    gone = tmp_path / 'fastrtps_0123456789abcdef'
    alive = tmp_path / 'fastrtps_fedcba9876543210'
    young = tmp_path / 'fastrtps_00112233445566ff'
    for segment in (gone, alive, young):
        segment.write_bytes(b'\0' * 64)
        aged(segment, old)
        lock = segment.with_name(segment.name + '_el')
        lock.touch()
        aged(lock, old if segment != young else 0)
    others = [tmp_path / 'fastrtps_port7004_el', tmp_path / 'fastrtps_0123_el']     # a port's, a short name
    for path in others:
        path.touch()
        aged(path, old)
    with open(alive.with_name(alive.name + '_el'), 'rb') as held:
        fcntl.flock(held, fcntl.LOCK_EX)                  # as its participant does for its life
        removed = shared_memory.remove_zombie_segments(tmp_path, now=young.with_name(young.name + '_el').stat().st_mtime)
    assert sorted(removed) == sorted([gone, gone.with_name(gone.name + '_el')])
    assert not gone.exists() and alive.exists() and young.exists()
    assert all(path.exists() for path in others)
