"""Errors a user can fix: bad input files. The CLI turns them into exit status 2."""
from __future__ import annotations


class InputError(Exception):
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
