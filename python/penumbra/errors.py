"""Exceptions raised by penumbra.

Every failure of the native library arrives as a :class:`PenumbraError` that
carries the library's status code and its message; bad user input (files,
arrays, scene descriptions) raises :class:`InputError`, which is also a
``ValueError`` so generic handlers keep working.
"""


class PenumbraError(RuntimeError):
    """A call into libpenumbra failed. ``status`` is the library's status code."""

    def __init__(self, message: str, status: int | None = None):
        super().__init__(message)
        self.status = status


class InputError(PenumbraError, ValueError):
    """The input (a file, an array, a scene description) is invalid; the message says what and where."""
