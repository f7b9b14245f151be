"""The status of an identification result (with a one-line reason beside it, never a raw
exception text): shared by the fits of this package."""
from __future__ import annotations

import enum


class FitStatus(enum.Enum):
    OK = 'ok'
    REFUSED = 'refused'          # the data cannot give the parameters: the reason says why
