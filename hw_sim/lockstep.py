"""Lock-step bookkeeping of the simulated hardware (design.md "Time"), without ROS.

hw_sim publishes the state of step k and advances to k+1 only when it holds a step-k
command for every axis. Commands carry the stamp of the state they answer, so a late or
stale command can never be applied to the wrong step: commands for an earlier step are
dropped (counted), commands for a later step are refused. A command for an unknown axis,
or with a length mismatch, is refused with a reason and changes nothing.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class LockStepStats:
    stale: int = 0          # commands for a step already taken
    refused: int = 0        # malformed or from the future
    last_refusal: str = ''

    def refuse(self, reason: str) -> str:
        self.refused += 1
        self.last_refusal = reason
        return reason


@dataclass
class LockStep:
    axis_names: tuple[str, ...]
    step: int = 0
    stats: LockStepStats = field(default_factory=LockStepStats)

    def __post_init__(self):
        self._index = {name: i for i, name in enumerate(self.axis_names)}
        self._commands: dict[int, float] = {}
        # the axis indices of name lists found valid (unique, known): each servo sends the
        # same names every step, so they are checked once per list, not per message
        self._valid: dict[tuple[str, ...], tuple[int, ...]] = {}

    def offer(self, step: int, names, values) -> str | None:
        """Take the commands of one message; returns the refusal reason, or None."""
        if step < self.step:
            self.stats.stale += 1
            return None
        reason = None
        if step > self.step:
            reason = f'command for step {step} while at step {self.step}'
        elif len(names) != len(values):
            reason = f'{len(names)} names but {len(values)} commands'
        else:
            names = tuple(names)
            indices = self._valid.get(names)
            if indices is None:
                reason = self._names_problem(names)
                indices = self._valid.get(names)
        if reason is not None:
            return self.stats.refuse(reason)
        self._commands.update(zip(indices, map(float, values)))
        return None

    KNOWN_NAME_LISTS = 16      # valid name lists kept (one per servo node; more only from odd publishers)

    def _names_problem(self, names: tuple[str, ...]) -> str | None:
        """Why a command's axis names are refused (duplicates, unknown axes), or None, the
        list then kept as valid."""
        if len(set(names)) != len(names):
            return 'duplicate axis names'
        unknown = [n for n in names if n not in self._index]
        if unknown:
            return f'unknown axes {", ".join(unknown)}'
        if len(self._valid) >= self.KNOWN_NAME_LISTS:
            self._valid.clear()
        self._valid[names] = tuple(self._index[n] for n in names)
        return None

    @property
    def missing(self) -> list[str]:
        return [n for i, n in enumerate(self.axis_names) if i not in self._commands]

    def complete(self) -> bool:
        return len(self._commands) == len(self.axis_names)

    def take(self) -> list[float]:
        """The step's commands in axis order; moves on to the next step."""
        commands = [self._commands[i] for i in range(len(self.axis_names))]
        self._commands.clear()
        self.step += 1
        return commands

    @property
    def in_hand(self) -> int:
        """How many axes have their command for the current step."""
        return len(self._commands)

    def take_held(self, held) -> list[float]:
        """The step's commands in axis order, `held[i]` for an axis without one (paced mode's
        zero-order hold); moves on to the next step."""
        commands = [self._commands.get(i, held[i]) for i in range(len(self.axis_names))]
        self._commands.clear()
        self.step += 1
        return commands

    def restart(self, step: int = 0) -> None:
        self._commands.clear()
        self.step = step


NOTHING_RECORDED = -1      # the step a recorder reports before it has written any state


@dataclass
class RecorderGate:
    """Flow control for a recorder (lock-step only): with ``window`` W > 0 steps, hw_sim does
    not advance from step k to k+1 while k - r > W, r = the step of the newest state the
    recorder reports written (:data:`NOTHING_RECORDED` before its first: then the session also
    holds step 0). Holding only delays a lock-step run, it never changes it.
    ``recorded`` is None until a recorder reports (then nothing is held) and again once it
    has left the graph. The holds are counted and timed (wall s) for the diagnostics."""
    window: int = 0
    recorded: int | None = None
    refused: int = 0
    last_refusal: str = ''
    lost: int = 0                        # recorders lost (their liveliness lease ran out)
    hold_count: int = 0                  # holds begun
    hold_time: float = 0.0               # wall s of the holds ended
    hold_started: float | None = None    # wall time the current hold began

    def holds(self, step: int) -> bool:
        return self.window > 0 and self.recorded is not None and step - self.recorded > self.window

    def track(self, holding: bool, now: float) -> None:
        """Count a hold that begins at `now`, time one that ends."""
        if holding and self.hold_started is None:
            self.hold_started = now
            self.hold_count += 1
        elif not holding and self.hold_started is not None:
            self.hold_time += now - self.hold_started
            self.hold_started = None

    def held_for(self, now: float) -> float:
        """Wall s held in all, the current hold up to `now` included."""
        return self.hold_time + (now - self.hold_started if self.hold_started is not None else 0.0)

    def refuse(self, reason: str) -> None:
        self.refused += 1
        self.last_refusal = reason
