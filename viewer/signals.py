"""SIGINT, SIGTERM and SIGHUP end the viewer as closing its window does: the frame loop stops, unsaved edits
are autosaved, one line is printed and the exit code is 128 + the signal (130, 143, 129).

Python runs a signal's handler only when the main thread is back in the interpreter, and an idle viewer
sleeps inside ``glfw.wait_events()``, which restarts its wait after the signal interrupts it. So the C-level
handler's wakeup byte (:func:`signal.set_wakeup_fd`) is read by a small thread that posts an empty glfw event
(``glfw.post_empty_event``, safe from any thread): the wait returns, the Python handler runs and records the
signal, and the loop sees it. The handler never raises: it may run inside a glfw callback, where an exception
would be printed and swallowed by ctypes.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable
from typing import Any

from particlesplat.core.errors import Interrupted

STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def raise_on_stop_signals() -> None:
    """Before the window exists: SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (one line, 128 + signal),
    whatever disposition the process inherited (a background job inherits SIGINT ignored)."""

    def handler(signum: int, _frame) -> None:
        raise Interrupted(signal.Signals(signum).name, signum)

    for s in STOP_SIGNALS:
        signal.signal(s, handler)


class SignalStop:
    """While entered: the first of :data:`STOP_SIGNALS` is recorded in :attr:`signum` and ``wake()`` is called from
    a helper thread so that a loop sleeping in C returns to Python. Leaving restores the previous handlers.

    Args:
        wake: wakes the event loop (``glfw.post_empty_event``); called from the helper thread.
    """

    def __init__(self, wake: Callable[[], None]) -> None:
        self.signum: int | None = None
        self._wake = wake
        self._old_handlers: dict[int, Any] = {}  # what signal.signal returned: a handler, SIG_DFL or None
        self._old_fd = -1
        self._pipe: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None

    @property
    def name(self) -> str:
        """The recorded signal's name (``SIGTERM``), or ``""``."""
        return signal.Signals(self.signum).name if self.signum is not None else ""

    def _handle(self, signum: int, _frame) -> None:
        if self.signum is None:
            self.signum = signum

    def _watch(self, fd: int) -> None:
        while True:
            try:
                data = os.read(fd, 64)
            except OSError:
                return
            if not data:  # the write end closed: leaving
                return
            try:
                self._wake()
            except Exception:  # noqa: BLE001 - glfw already terminated: nothing left to wake
                return

    def __enter__(self) -> SignalStop:
        r, w = os.pipe()
        os.set_blocking(w, False)
        self._pipe = (r, w)
        self._old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        for s in STOP_SIGNALS:
            self._old_handlers[s] = signal.signal(s, self._handle)
        self._thread = threading.Thread(target=self._watch, args=(r,), name="viewer-signal-wake", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *_exc) -> None:
        for s, old in self._old_handlers.items():
            signal.signal(s, old)
        signal.set_wakeup_fd(self._old_fd)
        if self._pipe is None:
            return
        r, w = self._pipe
        os.close(w)
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        os.close(r)
