"""The errors of forearm_dynamics: one class tree, each class mapped to its exit code here.

Why a tree (as the mcap library's exceptions.py): a caller catches what it can handle — a
BagError for any unusable bag, a BagNoData to try another topic — and a program's exit code
follows from the class (`exit_code_of`), never from matching message text. `str(err)` is
always one line meant for a user: it names the file, topic, key or parameter at fault.

    ForearmDynamicsError                 exit USAGE unless said otherwise
    ├── UsageError                       the request cannot be done as asked: an argument or
    │   │                                parameter value out of range or not fitting the
    │   │                                input (start_offset past the end of the bag, an
    │   │                                unknown estimator, a negative tolerance)
    │   └── (nodes.spec.ParameterError: a node parameter refused, with its name)
    ├── DataError                        exit DATA: the data are wrong or lost
    ├── ConfigMessageError (ValueError)  a `<node>/config` message that cannot be read back
    │                                    into the model it states (model_config.py)
    ├── MotionError (ValueError)         an OpenSim .mot/.sto table that cannot be used
    └── BagError                         a bag that cannot be read or written as asked
        ├── BagMissing                   no such file
        ├── BagEmpty                     a file of zero bytes
        ├── NotMcap                      not an MCAP file (no magic)
        ├── BagUnreadable                the OS refused to read it (permissions, I/O)
        ├── BagNoData                    no message at all, or none on the topic asked for
        ├── BagDamaged                   records past the first chunk that do not parse
        ├── ForeignBag                   a bag without the topic or message type asked for
        ├── SchemaError                  a message that does not decode as its schema says
        └── BagWriteError                exit DATA: writing failed (disk full, read-only);
            │                            the file was closed, what was written is readable
            ├── OutputExists             exit USAGE: the output exists (never overwritten
            │                            without --overwrite) or is a directory
            └── OutputNotCreated         exit USAGE: the output could not be created (a
                └── OutputDirMissing     read-only or full file system, no permission; its
                                         directory does not exist): nothing was written
"""

from __future__ import annotations

from . import exit_codes


class ForearmDynamicsError(Exception):
    """Base of every error this package raises on purpose; str() is one line for a user."""

    exit_code = exit_codes.USAGE


class UsageError(ForearmDynamicsError):
    """The request cannot be done as asked (an argument value, or one that does not fit the input)."""


class DataError(ForearmDynamicsError):
    """The data are wrong or lost."""

    exit_code = exit_codes.DATA


class ConfigMessageError(ForearmDynamicsError, ValueError):
    """A config message (`torque_node/config`) that cannot be read back into its model."""


class MotionError(ForearmDynamicsError, ValueError):
    """An OpenSim motion/storage table that cannot be used (one line naming the problem)."""


class BagError(ForearmDynamicsError):
    """A bag that cannot be read or written as asked."""


class BagMissing(BagError):
    """No such file."""


class BagEmpty(BagError):
    """A file of zero bytes."""


class NotMcap(BagError):
    """Not an MCAP file."""


class BagUnreadable(BagError):
    """The operating system refused to read the file."""


class BagNoData(BagError):
    """No message in the bag, or none on the topic asked for."""


class BagDamaged(BagError):
    """Records that do not parse (a damaged file, not merely a truncated one)."""


class ForeignBag(BagError):
    """The bag lacks the topic or message type asked for."""


class SchemaError(BagError):
    """A message that does not decode as its schema says."""


class BagWriteError(BagError):
    """Writing failed (disk full, read-only, I/O error); the file was closed.

    why: the operating system's reason alone, e.g. 'No space left on device'.
    """

    exit_code = exit_codes.DATA

    def __init__(self, message: str, why: str = ""):
        super().__init__(message)
        self.why = why or message


class OutputExists(BagWriteError):
    """The output file exists already (or is a directory): nothing was written."""

    exit_code = exit_codes.USAGE


class OutputNotCreated(BagWriteError):
    """The output file could not be created (read-only file system, no permission): nothing
    was written."""

    exit_code = exit_codes.USAGE


class OutputDirMissing(OutputNotCreated):
    """The output's directory does not exist: nothing was written."""


def exit_code_of(exc: BaseException) -> int:
    """The exit code a program ends with for `exc` (USAGE for anything not of this tree)."""
    return getattr(exc, "exit_code", exit_codes.USAGE) if isinstance(exc, ForearmDynamicsError) \
        else exit_codes.USAGE
