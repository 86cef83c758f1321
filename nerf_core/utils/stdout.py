"""A standard output that cannot be written: closed by the reader (``train ... | head``) or full
(``> /dev/full``). One home for naming it and for keeping the process's last writes from failing again.

``train`` treats a closed stdout like Ctrl-C (the reader is gone, the user wants it to stop: a
checkpoint is saved, ``nerf_core.runs.events``); any other failure is reported naming the file.
"""
from __future__ import annotations

import errno
import os
import sys


class StdoutClosed(KeyboardInterrupt):
    """The reader of stdout went away (EPIPE): stop the way Ctrl-C stops, saving the work."""


def stdout_name() -> str:
    """'stdout' and, where the system says, the file it is (``stdout (/dev/full)``)."""
    try:
        target = os.readlink(f"/proc/self/fd/{sys.__stdout__.fileno()}")
    except (OSError, AttributeError, ValueError):
        return "stdout"
    return f"stdout ({target})"


def silence_stdout() -> None:
    """Point stdout at the null device, so that later prints and the interpreter's last flush do not
    fail (and print 'Exception ignored ...') on the same broken file."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.__stdout__.fileno())
        os.close(null)
    except (OSError, AttributeError, ValueError):
        pass


def stdout_failure(exc: OSError) -> BaseException:
    """What a failed write to stdout becomes: StdoutClosed for a closed pipe, else an OSError that
    names stdout (the write's own error names no file). stdout is silenced either way."""
    if isinstance(exc.filename, str) and exc.filename.startswith("stdout"):
        return exc  # named already (NamedStdout)
    name = stdout_name()
    silence_stdout()
    if exc.errno == errno.EPIPE or isinstance(exc, BrokenPipeError):
        return StdoutClosed(f"{name} was closed")
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno or errno.EIO), name)


class NamedStdout:
    """sys.stdout for the command line: a failed write or flush raises ``stdout_failure`` (naming
    stdout, or StdoutClosed) instead of an OSError that names no file. Everything else is delegated."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise stdout_failure(exc) from None

    def flush(self):
        try:
            return self._stream.flush()
        except OSError as exc:
            raise stdout_failure(exc) from None

    def __getattr__(self, name):
        return getattr(self._stream, name)
