"""Following a goal sent to the running graph, client side (``machine-ctrl send|move`` and
the demo): the outcome of a goal from the trajectory node's status, and the progress shown
until the motion ends."""
from __future__ import annotations

import sys
import time


def goal_outcome(client, after: int, refused: int) -> str | None:
    """'refused', 'fault', 'done' or None (not yet) for a goal sent when `after` statuses
    and `refused` refusals had been seen."""
    status = client.status()
    if int(status.get('rejected_goals', 0)) > refused:
        return 'refused'
    if any(s.message == 'fault' for s in client.statuses[after:]):
        return 'fault'
    return 'done' if client.states_seen(after, ['running', 'idle']) else None


def follow_goal(client, publish, timeout: float, out=sys.stdout) -> int:
    """Send with `publish()`, show the progress until the motion ends; 0 when it ran to
    its end, 1 when refused, faulted, stopped early or timed out (reason on stderr)."""
    from machine_ctrl.app.bringup import StateReporter
    after, refused = len(client.statuses), int(client.status().get('rejected_goals', 0))
    publish()
    reporter = StateReporter(client, out)
    reporter.seen = after
    deadline = time.monotonic() + timeout
    while (outcome := goal_outcome(client, after, refused)) is None:
        if time.monotonic() > deadline:
            print(f'machine-ctrl: timed out after {timeout:g} s; status {client.status()}', file=sys.stderr)
            return 1
        reporter.poll()
        time.sleep(0.05)
    reporter.poll()
    status = client.status()
    if outcome == 'refused':
        print(f'machine-ctrl: refused: {status["last_rejection"]}', file=sys.stderr)
        return 1
    if outcome == 'fault':
        print(f'machine-ctrl: machine faulted: {status.get("fault", "")}', file=sys.stderr)
        return 1
    progress = float(status.get('progress', 0))
    if progress < 1.0:
        print(f'machine-ctrl: the motion ended at {progress * 100:.1f} % (stopped)', file=sys.stderr)
        return 1
    print(f'done: {status.get("motion", "")}', file=out)
    return 0
