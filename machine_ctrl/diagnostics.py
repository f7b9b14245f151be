"""What the nodes and their sessions report on /diagnostics about refused inputs, ROS-free
(beside :mod:`machine_ctrl.contract`) so that the cores keep it the same way as the nodes:
the count of refused messages or goals and the last reason, the one-line text of an
error that refuses an input, and a peer's liveliness as a node concludes it."""
from __future__ import annotations

from collections.abc import Callable


class Rejections:
    """Counts refused inputs and keeps the last reason; each refusal is also handed to
    `warn` as one line (a node logs it, throttled)."""

    def __init__(self, warn: Callable[[str], None]):
        self.warn = warn
        self.count = 0
        self.last = ''

    def add(self, what: str, reason: str) -> None:
        self.count += 1
        self.last = f'{what}: {reason}'
        self.warn(f'rejected {what}: {reason}')


def error_text(exc: BaseException) -> str:
    """The reason an error gives for refusing an input: a ValueError's message as it is
    (it says what is wrong with the input), any other error with its type."""
    return str(exc) if isinstance(exc, ValueError) else f'{type(exc).__name__}: {exc}'


class PeerLiveliness:
    """Whether a peer node is lost, as a node concludes it from the peer's liveliness lease
    (README "Faults"): the lease ran out and nothing was heard from the peer for `confirm` s
    (wall) since — a reader starved by its own node's long callback reports false losses, so
    one of the peer's messages (its 1 Hz /diagnostics) arriving after the report cancels it.
    Feed it :meth:`alive`, :meth:`heard` and :meth:`losing` (on each loss report and from a
    timer while lost, more often than every `gap` s); :meth:`losing` says True once, when
    the loss is confirmed. A call more than `gap` s after the one before starts the
    confirmation over: the watching node itself did not run meanwhile, and the peer's
    messages may be waiting behind it (or, in one process, the peer did not run either). A
    watcher whose checks all come more than `gap` s apart confirms nothing until it runs
    regularly again (a stall of its own is its own check's to report: the trajectory node's
    `trajectory stalled` while a goal runs)."""

    def __init__(self, confirm: float, gap: float):
        self.confirm, self.gap = confirm, gap
        self.lost = False                    # confirmed, and not back yet
        self._since: float | None = None     # reported lost at (not confirmed yet)
        self._checked: float | None = None   # the last losing() call while reported lost

    def alive(self) -> None:
        self.lost, self._since, self._checked = False, None, None

    def heard(self, now: float) -> None:
        if self._since is not None and now > self._since:
            self._since = None

    def losing(self, now: float) -> bool:
        if self.lost:
            return False
        stalled = self._checked is not None and now - self._checked > self.gap
        self._checked = now
        if self._since is None or stalled:
            self._since = now
            return False
        if now - self._since < self.confirm:
            return False
        self._since, self._checked, self.lost = None, None, True
        return True
