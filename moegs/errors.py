"""Exceptions the command line turns into one clear line (no torch import here, so ``moegs --help`` and
``moegs list`` stay light)."""

from __future__ import annotations


class TrainingInterrupted(RuntimeError):
    """SIGINT / SIGTERM stopped training after a finished step; the message names the checkpoint."""


class IntegrityError(ValueError):
    """A stored file does not match the hash recorded when it was written, or cannot be parsed; the
    message names the file."""


INPUT_ERRORS = (ValueError, KeyError, OSError, TypeError)
"""Errors caused by what the user passed or what is on disk: exit status 2. ``TypeError`` is here because
loaders raise it for a JSON field of the wrong type."""


CLEAR_ERRORS = (*INPUT_ERRORS, FloatingPointError)
"""Errors whose message says all (training that diverged names the step and the last checkpoint)."""


def describe_error(err: BaseException) -> str:
    """One line for ``err``: the message of a clear error, the type and message of anything else."""
    if isinstance(err, KeyError) and err.args:
        message = str(err.args[0])
    else:
        message = str(err) or type(err).__name__
    message = " ".join(message.split())  # one line
    if isinstance(err, CLEAR_ERRORS):
        return message
    return f"internal error: {type(err).__name__}: {message} (run with --debug for the traceback)"
