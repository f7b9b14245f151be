"""The servo side of lock-step, without ROS (design.md "Time"): answer each state of the
simulated machine exactly once, from the inputs of its step.

hw_sim sends the state of step k and waits for every axis's step-k command, re-sending the
state while it waits; the per-step nodes (servo, dual stage) answer through a
:class:`StepAnswerer`. The ROS side (machine_ctrl.ros.node_common.StepResponder) only adds
a wall-clock timer and passes the wall time in, so this runs on fake time in tests.
"""
from __future__ import annotations

from machine_ctrl.model.errors import InvalidMessage


class StepAnswerer:
    """Answers each step's state exactly once.

    `ready(step)` says whether the inputs for the step are there; the answerer waits for
    them up to `timeout` s (wall, counted from the step's first arrival), then answers anyway
    (`compute` handles the gap) — but only once `streaming()` says every input stream has
    delivered at least once: an input that never started is waited for indefinitely, so a
    lock-step run does not depend on how fast the graph came up.
    `compute(step, state)` returns the answer, or None to give no answer; `send(answer)`
    sends it. A repeated stamp (hw_sim re-sends while waiting) gets the cached answer again;
    older stamps are ignored. A stamp more than one step ahead of the newest step seen is
    refused (InvalidMessage) unless it is confirmed: it comes again (hw_sim re-sends a state
    it waits on in lock-step) or the next state is its successor (states lost on the way: in
    paced mode hw_sim does not wait, and a queue overrun under load drops states; the
    successor is then answered). hw_sim never skips a step, so a stray message with a
    future stamp cannot make the node skip the real steps (and stop the machine on missing
    commands): the real step that follows it is not its successor.
    """

    def __init__(self, send, ready, compute, timeout: float, streaming):
        self.send, self.ready, self.compute, self.timeout = send, ready, compute, timeout
        self.streaming = streaming
        self.pending = None                  # (step, state) waiting for its inputs
        self.pending_since = 0.0             # wall time the pending step first arrived
        self.answered = None                 # (step, answer) of the newest step answered
        self.newest = None                   # newest step taken
        self.skip_candidate = None           # a step ahead of newest + 1, seen once

    @property
    def answered_step(self) -> int:
        return self.answered[0] if self.answered else 0

    def has_answered(self, step: int) -> bool:
        """Whether `step` (or a later one) has been answered: its inputs are no longer needed."""
        return self.answered is not None and step <= self.answered[0]

    @property
    def waiting(self) -> bool:
        return self.pending is not None

    def on_state(self, step: int, state, now: float) -> None:
        """The state of `step` arrived at wall time `now`."""
        if self.answered is not None and step <= self.answered[0]:
            if step == self.answered[0]:
                self.send(self.answered[1])
            return
        if self.newest is not None and step > self.newest + 1:
            candidate = self.skip_candidate
            if candidate is None or step not in (candidate, candidate + 1):
                self.skip_candidate = step
                raise InvalidMessage(f'state of step {step} skips ahead of step {self.newest + 1} '
                                     '(taken only if it comes again or its next step follows)')
        self.newest = step if self.newest is None else max(self.newest, step)
        self.skip_candidate = None
        if self.pending is None or self.pending[0] != step:     # a re-send keeps its first arrival
            self.pending_since = now
        self.pending = (step, state)
        self.poke()

    def poke(self, give_up: bool = False) -> None:
        """Answer the pending step if its inputs are there (or when giving up on them)."""
        if self.pending is None or not (give_up or self.ready(self.pending[0])):
            return
        step, state = self.pending
        self.pending = None
        answer = self.compute(step, state)
        if answer is not None:
            self.answered = (step, answer)
            self.send(answer)

    def on_timer(self, now: float) -> None:
        """Give up waiting for the pending step's inputs once `timeout` has passed (and
        every input stream has started)."""
        if self.pending is not None and self.streaming() and now - self.pending_since > self.timeout:
            self.poke(give_up=True)
