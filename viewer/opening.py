"""Opening a scene (a model scene, or a Gaussian file) on a thread while the window goes on drawing the one shown: the
status line says what is being done and for how long ("opening scene_00019: loading the model
assets/robot/model.pt (3 s)"), and the new scene takes the window's place once it is ready. The loading itself is
:func:`viewer.loading.load_session`'s (models are kept: switching back is quick)."""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from particlesplat.formats.splat_files import SUFFIXES

if TYPE_CHECKING:
    from particlesplat.core.viewpoints import View

    from .session import Scene

PROGRESS_EVERY = 0.25  # seconds between redraws of the progress line while a scene opens


def open_arguments(args: argparse.Namespace, path: str) -> argparse.Namespace:
    """The viewer's options ``args`` with ``path`` as what to open: a Gaussian file (``--ply``) or a scene folder
    (``--scene``), without the first scene's edits and context frames. A missing path that names a Gaussian file's
    suffix is taken for one (so the error names it)."""
    p = Path(path)
    out = argparse.Namespace(**vars(args))
    is_file = p.is_file() or (not p.exists() and p.name.lower().endswith(SUFFIXES))
    out.scene, out.ply, out.edits, out.context = (None, str(p), None, None) if is_file else (str(p), None, None, None)
    return out


def load_opened(
    args: argparse.Namespace, progress: Callable[[str], None], frame: Callable[[Scene], View]
) -> tuple[Scene, View]:
    """The session of ``args`` (:func:`viewer.loading.load_session`) and the view it opens with: ``frame(session)``
    (the app's default view of a scene); ``progress`` hears each stage."""
    from .loading import load_session

    session = load_session(args, progress)
    progress("framing it")
    return session, frame(session)


@dataclass
class Opening:
    """A scene being opened on a thread.

    Attributes:
        path: what is opened, as given.
        stage: what it does now ("loading the model ...", "encoding ...").
        started: ``time.perf_counter()`` when it began.
        result: (the session, its default view) once loaded; error: what went wrong instead (a bad path or file).
    """

    path: str
    stage: str = "starting"
    started: float = field(default_factory=time.perf_counter)
    result: tuple[Scene, View] | None = None
    error: BaseException | None = None
    thread: threading.Thread | None = None

    @property
    def done(self) -> bool:
        return self.thread is not None and not self.thread.is_alive()

    def line(self, now: float | None = None) -> str:
        """The status line while it works: ``opening NAME: STAGE (N s)``."""
        elapsed = (time.perf_counter() if now is None else now) - self.started
        return f"opening {Path(self.path).name or self.path}: {self.stage} ({elapsed:.0f} s)"

    def wait(self, timeout: float | None = None) -> None:
        if self.thread is not None:
            self.thread.join(timeout)


def start_opening(args: argparse.Namespace, path: str, frame: Callable[[Scene], View]) -> Opening:
    """Open ``path`` (:func:`open_arguments`, :func:`load_opened` with ``frame``) on a daemon thread; returns at
    once."""
    opening = Opening(path)
    options = open_arguments(args, path)

    def progress(stage: str) -> None:
        opening.stage = stage

    def work() -> None:
        try:
            opening.result = load_opened(options, progress, frame)
        except Exception as e:  # noqa: BLE001 - a bad path or file is shown on the status line, never fatal
            opening.error = e

    opening.thread = threading.Thread(target=work, name=f"open {Path(path).name}", daemon=True)
    opening.thread.start()
    return opening
