"""What the nodes and their sessions report on /diagnostics about refused inputs, ROS-free
(beside :mod:`machine_ctrl.contract`) so that the cores keep it the same way as the nodes:
the count of refused messages or goals and the last reason, and the one-line text of an
error that refuses an input."""
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
