"""The exit statuses of every ``taiji2`` verb, one table (README, "Exit statuses").

A script that runs a verb can tell from the status alone what happened: the run and its evaluation
(0, 3), the user's input (2), what could not be computed from the data (4), or a failure of the tool or
of a node (1).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitStatus"]


class ExitStatus(IntEnum):
    """Exit status of a ``taiji2`` verb."""

    #: done; where the verb judges requirements, every requirement is met
    OK = 0
    #: the verb or one of its nodes failed (its own error line says which and why)
    FAILED = 1
    #: bad input (arguments, files, parameters): one line ``error: taiji2 <verb>: ...`` before anything ran
    BAD_INPUT = 2
    #: the run is complete and its results determined, but not every requirement is met (the verdict names them)
    NOT_MET = 3
    #: a result cannot be determined from the data (e.g. a stream without a usable sample): one line naming
    #: the stream and the reason; no estimate is printed as if it were one
    UNDETERMINED = 4
