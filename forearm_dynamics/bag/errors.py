"""Errors of the bag package: a kind (for exit codes and tests) and one readable line."""

from __future__ import annotations


class BagError(Exception):
    """A bag that cannot be read or written as asked.

    kind: 'missing', 'empty', 'not_mcap', 'unreadable', 'no_data', 'damaged', 'foreign',
    'schema', 'exists', 'write'. str(err) is one line meant for a user.
    """

    def __init__(self, kind: str, message: str):
        super().__init__(message)
        self.kind = kind


class BagWriteError(BagError):
    """Writing failed (disk full, read-only, missing directory); the file was closed."""

    def __init__(self, message: str, kind: str = "write", why: str = ""):
        super().__init__(kind, message)
        self.why = why or message  # the OS's reason alone, e.g. 'No space left on device'
