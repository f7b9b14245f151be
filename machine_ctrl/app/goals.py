"""Following a goal sent to the running graph, client side (``machine-ctrl send|move`` and
the demo): the request is stamped (the wall clock), the goal found by that stamp in the
trajectory node's goal status (its id), and followed by id until it ends — its states and
the motion's progress shown — with the outcome as the exit status."""
from __future__ import annotations

import sys
import time

# s (wall) to wait for a finished goal's /diagnostics entry (its reason, its label), which
# travels on another topic than the goal status. assumed: 10 s; it normally follows within
# milliseconds, but a machine under load may delay it by seconds (only a lost entry waits
# this long, and the outcome is then shown without its reason)
REASON_WAIT = 10.0


def goal_outcome(client, stamp, goal_id: str | None = None) -> tuple[str | None, str | None]:
    """(goal id or None, its newest state or None) for the goal sent with `stamp` (or of
    `goal_id`, when known)."""
    goal_id = goal_id or client.goal_of(stamp)
    return goal_id, (client.goal_state(goal_id) or None) if goal_id else None


def _entry(client, goal_id: str, state: str) -> dict:
    """The goal's /diagnostics entry for `state`, waited for a little ({} if it never came)."""
    deadline = time.monotonic() + REASON_WAIT
    while True:
        entry = client.goal_entries.get(goal_id, {})
        if entry.get('status') == state or time.monotonic() > deadline:
            return entry
        time.sleep(0.02)


def follow_goal(client, publish, timeout: float, out=sys.stdout, known_id=None) -> int:
    """Send with `publish(stamp)`, follow the goal by its id, show its states and the
    progress until it ends: 0 when it succeeded; 1 when refused or aborted (planning failed,
    machine faulted, hw_sim lost), canceled (stopped), the trajectory node lost (its
    liveliness lease ran out: it can no longer say what became of the goal) or timed out,
    with the reason in one line on stderr. `known_id()`: the goal's id when the request had
    no stamp (a service call answered with it); default: found by the stamp."""
    from machine_ctrl.app.bringup import StateReporter
    from machine_ctrl.app.client import TERMINAL
    stamp = client.stamp_now()
    reporter = StateReporter(client, out)
    reporter.seen = len(client.statuses)
    publish(stamp)
    deadline = time.monotonic() + timeout
    shown: list[str] = []
    goal_id = state = None
    while True:
        goal_id, state = goal_outcome(client, stamp, known_id and known_id())
        history = client.goal_states.get(goal_id, []) if goal_id else []
        for seen in history[len(shown):]:
            shown.append(seen)
            print(f'goal {goal_id}: {seen}', file=out, flush=True)
        reporter.poll()
        if state in TERMINAL:
            break
        if client.trajectory_lost is not None:
            where = f'goal {goal_id} was {state}' if goal_id else 'the goal never appeared in the goal status'
            print(f'machine-ctrl: lost: {client.trajectory_lost}; {where}', file=sys.stderr)
            return 1
        if time.monotonic() > deadline:
            where = f'goal {goal_id} {state}' if goal_id else 'the goal never appeared in the goal status'
            print(f'machine-ctrl: timed out after {timeout:g} s; {where}; status {client.status()}', file=sys.stderr)
            return 1
        time.sleep(0.05)
    entry = _entry(client, goal_id, state)
    if entry.get('status') == state:
        reason = entry.get('reason') or state
    else:               # not the status's last_rejection: it may be another goal's
        reason = f'{state} (its reason did not come within {REASON_WAIT:g} s)'
    if state == 'succeeded':
        print(f'done: {entry.get("label") or client.status().get("motion", "")} (goal {goal_id})', file=out)
        return 0
    if state == 'aborted':
        verb = 'refused' if 'executing' not in shown and 'machine faulted' not in reason else 'aborted'
        print(f'machine-ctrl: {verb}: {reason}', file=sys.stderr)
    else:
        print(f'machine-ctrl: canceled: {reason}', file=sys.stderr)
    return 1
