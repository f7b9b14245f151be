"""The goals of a trajectory session and their lifecycle, ROS-free (README "For ROS users",
"Goal status"). The trajectory node publishes them as action_msgs/GoalStatusArray on
contract.GOAL_STATUS and every change as a /diagnostics entry (GoalStatus has no text).

Every goal the node receives — a tool path, a G-code program, a freeform cut, a joint goal,
home — gets an id, accepted or not. The id is a UUID (unique_identifier_msgs/UUID in action_msgs/GoalInfo) made
deterministically from the node's goal counter and the request's stamp (uuid5 in
:data:`GOAL_NAMESPACE`), so lock-step runs stay reproducible; GoalInfo.stamp is the
request's header.stamp as sent (for home, a program and a freeform cut, which have no
request header: the sim time the node received it), so a client that stamps its request uniquely (``machine-ctrl
send|move`` use the wall clock) finds its goal by the stamp. The node does not schedule by
the stamp: a goal starts as soon as it can.

Lifecycle (:class:`GoalState`: the action_msgs/GoalStatus codes):

* accepted: taken on (a tool path while it is planned, a joint goal or home at once);
* executing: the sim time has reached the motion's first step (the servos follow it); a
  hold keeps the goal executing (GoalStatus has no "held");
* canceling: a stop or cancel ramps it to rest; canceled once at rest;
* succeeded: the motion has played out and stands at rest at its end;
* aborted: refused on receipt (invalid, busy, faulted, no machine state yet), planning
  failed, the machine faulted under way, the node stalled, or the node carrying its
  reference (compensation) was lost; the reason goes with the change.

:class:`GoalBook` keeps the recent goals (the last :data:`KEEP`, the active one always) in
the order they came.
"""
from __future__ import annotations

import uuid
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum

from machine_ctrl import contract

# assumed: a fixed namespace of our own for the goal ids (uuid5), so the same goals in the
# same order give the same ids in every run
GOAL_NAMESPACE = uuid.UUID('6d616368-696e-6563-7472-6c2d676f616c')
KEEP = contract.GOAL_STATUS_KEEP    # goals kept in the status array (the active one always)


class GoalState(IntEnum):
    """action_msgs/msg/GoalStatus codes."""
    UNKNOWN = 0
    ACCEPTED = 1
    EXECUTING = 2
    CANCELING = 3
    SUCCEEDED = 4
    CANCELED = 5
    ABORTED = 6

    @property
    def text(self) -> str:
        return self.name.lower()

    @property
    def terminal(self) -> bool:
        return self in (GoalState.SUCCEEDED, GoalState.CANCELED, GoalState.ABORTED)


@dataclass
class Goal:
    id: bytes                           # 16 bytes (unique_identifier_msgs/UUID)
    stamp: tuple[int, int]              # (sec, nanosec) of the request (GoalInfo.stamp)
    kind: str                           # 'path', 'program', 'freeform', 'joint goal', 'home'
    label: str                          # e.g. 'joint goal (2 points)'
    state: GoalState = GoalState.UNKNOWN
    reason: str = ''                    # why it was aborted or canceled

    @property
    def uuid(self) -> str:
        return str(uuid.UUID(bytes=self.id))

    def values(self) -> dict:
        """The goal's /diagnostics entry (key -> value)."""
        return {'goal_id': self.uuid, 'status': self.state.text, 'status_code': int(self.state),
                'reason': self.reason, 'kind': self.kind, 'label': self.label,
                'stamp': f'{self.stamp[0]}.{self.stamp[1]:09d}'}


class GoalBook:
    """The session's goals. `on_change(goal)` is called after every change of a goal's
    state (the node publishes the array and the goal's entry)."""

    def __init__(self, on_change: Callable[[Goal], None], keep: int = KEEP):
        self.on_change = on_change
        self.keep = keep
        self.count = 0                  # goals received: the id counter
        self.goals: list[Goal] = []     # oldest first
        self.active: Goal | None = None  # the goal of the motion under way (or planned)

    def new(self, kind: str, label: str, stamp: tuple[int, int] = (0, 0)) -> Goal:
        """A goal just received (state unknown until :meth:`set`)."""
        sec, nanosec = (int(v) for v in stamp)
        goal_id = uuid.uuid5(GOAL_NAMESPACE, f'{self.count}:{sec}.{nanosec:09d}').bytes
        self.count += 1
        goal = Goal(goal_id, (sec, nanosec), kind, label)
        self.goals.append(goal)
        if len(self.goals) > self.keep:
            drop = next(g for g in self.goals if g is not self.active)
            self.goals.remove(drop)
        return goal

    def set(self, goal: Goal, state: GoalState, reason: str = '') -> None:
        """Move `goal` to `state` (a terminal goal stays as it is); the active goal is the
        latest accepted one until it ends."""
        if goal.state.terminal or (goal.state == state and not reason):
            return
        goal.state = state
        if reason:
            goal.reason = reason
        if state == GoalState.ACCEPTED:
            self.active = goal
        elif state.terminal and goal is self.active:
            self.active = None
        self.on_change(goal)

    def refuse(self, kind: str, label: str, stamp, reason: str) -> Goal:
        """A goal refused on receipt: aborted with the reason."""
        goal = self.new(kind, label, stamp)
        self.set(goal, GoalState.ABORTED, reason)
        return goal

    def find(self, goal_id: bytes) -> Goal | None:
        return next((g for g in self.goals if g.id == goal_id), None)
