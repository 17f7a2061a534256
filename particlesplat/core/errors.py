"""The error policy shared by every command and the viewer.

A user-caused error (bad file, bad argument, unwritable output) is a :class:`UserError` (each reader has its
subclass: ``SceneFormatError``, ``ConfigError``, ``CheckpointError``, ...) or an ``OSError`` about a path the
user gave: the command prints one line naming the file and the field and exits with :data:`EXIT_USER`.
Anything else, a bare ``ValueError`` included, is a bug and keeps its traceback. Ctrl-C prints one line and
exits with :data:`EXIT_INTERRUPTED`. Warnings about legal but implausible input (:class:`InputWarning`) are
printed as one line each.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

EXIT_USER = 2  # bad input, as argparse exits on a bad argument
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C
REPR_LIMIT = 80  # characters of a value echoed in a message


class UserError(ValueError):
    """Bad input from the user; the message is one line naming the file and the field."""


class OptionError(UserError):
    """A command-line option with a value that cannot be used; the message names the option."""


class InputWarning(UserWarning):
    """Legal but implausible input (e.g. a focal length of a thousandth of a pixel); the message names the file and
    the field. Commands print it as one line and go on."""


class Interrupted(KeyboardInterrupt):
    """A command stopped by a signal after it saved what it had (the message says what and where).

    ``signum`` is the signal (SIGINT, SIGTERM): the exit code is 128 + signum, as a shell reports it."""

    def __init__(self, message: str = "", signum: int = 2) -> None:
        super().__init__(message)
        self.signum = signum


def short_repr(value: object, limit: int = REPR_LIMIT) -> str:
    """``repr(value)`` cut to ``limit`` characters (``...`` marks the cut), so that a message never echoes
    unbounded input. Containers are walked lazily: a value built from YAML aliases is not expanded beyond
    ``limit`` characters."""
    out: list[str] = []
    size = 0

    def emit(text: str) -> bool:
        nonlocal size
        out.append(text)
        size += len(text)
        return size <= limit

    def walk(v: object, depth: int) -> bool:
        if depth > 20:
            return emit("...")
        if isinstance(v, dict):
            if not emit("{"):
                return False
            for i, (k, item) in enumerate(v.items()):
                if (i and not emit(", ")) or not walk(k, depth + 1) or not emit(": ") or not walk(item, depth + 1):
                    return False
            return emit("}")
        if isinstance(v, (list, tuple)):
            if not emit("[" if isinstance(v, list) else "("):
                return False
            for i, item in enumerate(v):
                if (i and not emit(", ")) or not walk(item, depth + 1):
                    return False
            return emit("]" if isinstance(v, list) else ")")
        if isinstance(v, (str, bytes)):
            return emit(repr(v[: limit + 1]))
        return emit(repr(v)[: limit + 1])

    walk(value, 0)
    text = "".join(out)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def one_line(message: object, limit: int = 2000) -> str:
    """The message of an error as one line (newlines folded), at most ``limit`` characters."""
    text = " ".join(str(message).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def is_user_error(e: BaseException) -> bool:
    """User-caused: :class:`UserError` (file formats, configs, options, budgets) and OSError (missing, unreadable
    or unwritable files, a full disk). A bare ValueError, MemoryError, RuntimeError and the rest are bugs."""
    return isinstance(e, (UserError, OSError))


@contextmanager
def blame(what: str, *errors: type[BaseException]) -> Iterator[None]:
    """Turn ``errors`` raised inside into a :class:`UserError` naming ``what`` (the scene or checkpoint that caused
    them), e.g. the renderer's refusal of non-finite Gaussians decoded from a checkpoint of huge weights."""
    try:
        yield
    except errors as e:
        raise UserError(f"{what}: {one_line(e, 300)}") from None


def warn_input(message: str) -> None:
    """Warn about legal but implausible input (:class:`InputWarning`); each distinct message is shown once."""
    warnings.warn(message, InputWarning, stacklevel=2)


def run_command(prog: str, fn: Callable[[], int]) -> int:
    """Run ``fn`` under the error policy: one line on stderr and exit 2 for a user error, one line and
    exit 130 for Ctrl-C; other exceptions propagate with their traceback. An :class:`InputWarning` is one
    line, ``PROG: warning: MESSAGE``."""
    show = warnings.showwarning

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, InputWarning):
            print(f"{prog}: warning: {one_line(message)}", file=sys.stderr)
        else:
            show(message, category, filename, lineno, file, line)

    warnings.showwarning = one_line_warning
    try:
        return int(fn() or 0)
    except KeyboardInterrupt as e:
        detail = f" ({one_line(e)})" if str(e) else ""
        print(f"{prog}: interrupted{detail}", file=sys.stderr)
        return 128 + e.signum if isinstance(e, Interrupted) else EXIT_INTERRUPTED
    except Exception as e:
        if not is_user_error(e):
            raise
        print(f"{prog}: error: {one_line(e)}", file=sys.stderr)
        return EXIT_USER
    finally:
        warnings.showwarning = show


def stop_signal_handler(message: str = "") -> Callable[[int, object], None]:
    """A signal handler that stops a command as Ctrl-C does: it raises :class:`Interrupted` (``message``, the
    signal), so every ``finally`` block and atomic write unwinds (temporary files removed, locks released), then
    :func:`run_command` prints one line and returns 128 + the signal (143 for SIGTERM)."""

    def handler(signum: int, _frame: object) -> None:
        raise Interrupted(message, signum)

    return handler


def stop_on_sigterm() -> None:
    """Make SIGTERM (``kill PID``, a service manager, a job scheduler's time limit) stop the process as Ctrl-C does
    (:func:`stop_signal_handler`); the console script calls it for every command before the command runs. A
    command that stops more gracefully (``train``: finish the step, save) installs its own while it runs and puts
    this one back. Only the main thread may install handlers: elsewhere nothing changes."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, stop_signal_handler("SIGTERM"))


def end_at_once_if_interrupted(code: int) -> int:
    """A console script's last step: after Ctrl-C or a stop signal (``code`` > 128, the one line already printed)
    flush the output and end the process now, skipping the interpreter's teardown of torch and the model (0.7-1.2 s
    measured on a loaded 2-core machine, which made Ctrl-C feel ignored). The work was unwound before (its
    ``finally`` blocks ran: temporary files removed, locks released). Any other code is returned."""
    if code > 128:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)
    return code
