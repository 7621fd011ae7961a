"""What can go wrong that a user should hear about in one line, not a traceback.

:class:`CalbenchError` is the base: the command line turns any of them into a message and an
exit status (2 for bad input, :class:`InputError`). :class:`StaticsError` says that a
configuration has no static equilibrium (a degenerate loop, a diverging solve); a campaign
reports it as bad input naming the pose.
"""

from __future__ import annotations

import numpy as np


class CalbenchError(Exception):
    """Base of every error calbench raises on purpose (as opposed to a bug)."""


class InputError(CalbenchError):
    """Bad user input, located by file and key, with what was expected.

    The message reads ``FILE: KEY: expected EXPECTED, got GOT`` so a user can find
    and fix the offending line without reading a traceback.
    """

    def __init__(self, file: object, key: str, expected: str, got: object = None):
        self.file = str(file)
        self.key = key
        self.expected = expected
        self.got = got
        msg = f"{self.file}: {key}: expected {expected}"
        if got is not None:
            msg += f", got {got!r}"
        super().__init__(msg)


class StaticsError(CalbenchError, np.linalg.LinAlgError):
    """No equilibrium can be computed: the KKT matrix is singular (a degenerate configuration,
    e.g. a degenerate kinematic loop) or the solution is not finite.
    Also a LinAlgError, so numerical callers that catch those keep working."""


__all__ = ["CalbenchError", "InputError", "StaticsError"]
