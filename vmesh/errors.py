"""Exceptions with one-line, user-facing messages."""

from __future__ import annotations

from pathlib import Path


class VmeshError(Exception):
    """Base class of every error vmesh reports to a user.

    The message is one line; when a file is involved it starts with the file's path
    so that the command line can print ``vmesh: error: <file>: <problem>``.
    """

    def __init__(self, message: str, path: str | Path | None = None):
        self.path = None if path is None else str(path)
        self.problem = " ".join(str(message).split())
        super().__init__(self.problem if path is None else f"{self.path}: {self.problem}")


class InputError(VmeshError):
    """A user's input file is missing, empty, corrupt or of an unknown format."""


class ParameterError(VmeshError):
    """An unknown filter or parameter, or a value of the wrong type or out of range."""


class ChainError(VmeshError):
    """A filter chain that cannot run (bad file, missing layer, failed filter)."""


class MeshingError(VmeshError):
    """A stage could not produce a valid result (e.g. an invalid block)."""


class Stopped(BaseException):
    """The run was stopped by a signal (SIGTERM from ``timeout`` or a batch scheduler,
    SIGHUP); a BaseException like KeyboardInterrupt, so that no ``except Exception``
    swallows it and every ``finally`` clean-up runs."""

    def __init__(self, signal_name: str, signal_number: int = 15):
        self.signal_name = signal_name
        self.signal_number = signal_number
        super().__init__(f"stopped by {signal_name}")


def stop_behind(exc: BaseException) -> BaseException | None:
    """The KeyboardInterrupt or :class:`Stopped` that caused ``exc``, if any.

    A signal that lands while a C extension initialises or runs a callback comes back as
    an ordinary error (``ImportError: initialization failed`` from a module import) with
    the stop as its cause or context: it is still a stop, not a bug.

    Parameters
    ----------
    exc : BaseException
        The exception caught; its chain of causes and contexts is followed (each link
        once, so a cycle ends the search).

    Returns
    -------
    BaseException or None
        ``exc`` itself or the first exception in its chain that is a KeyboardInterrupt or
        a :class:`Stopped`; None when there is none (a real error).
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, (KeyboardInterrupt, Stopped)):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
