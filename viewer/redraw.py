"""When the viewer's frame loop draws: only on input or change, so an idle viewer sleeps.

The loop sleeps in ``glfw.wait_events()`` until a window event (input, resize, expose, focus)
arrives, then draws a few frames (imgui needs a frame or two to show the effect of an input).
Timed redraws cover what changes without input: the full-scale frame that follows a camera
motion, and the blinking cursor of an active text field.
"""

from __future__ import annotations

from dataclasses import dataclass

SETTLE_FRAMES = 3  # frames drawn after each event (imgui shows an input's effect within two)
CURSOR_BLINK = 0.4  # seconds between redraws while a text field is active (imgui's cursor blinks)


@dataclass
class RedrawSchedule:
    """Frames still to draw and the time of the next timed redraw.

    Attributes:
        pending: frames to draw now (the first frames of a window, or after an event).
        wake_at: ``time.perf_counter()`` time of the next timed redraw, or None.
        events: window events seen (for diagnostics and tests).
    """

    pending: int = SETTLE_FRAMES
    wake_at: float | None = None
    events: int = 0

    def notify(self, *_args) -> None:
        """A window event arrived (any glfw callback's arguments): draw the next frames."""
        self.events += 1
        self.pending = SETTLE_FRAMES

    def timeout(self, now: float) -> float | None:
        """Seconds the loop may sleep waiting for events: 0 = draw now, None = until an event."""
        if self.pending > 0:
            return 0.0
        if self.wake_at is None:
            return None
        return max(0.0, self.wake_at - now)

    def due(self, now: float) -> bool:
        """After the wait: whether to draw a frame now."""
        return self.pending > 0 or (self.wake_at is not None and now >= self.wake_at)

    def drawn(self, changed: bool, wake_at: float | None) -> None:
        """A frame was drawn. ``changed``: it changed the scene or the session (draw one more frame so
        the panel shows it); ``wake_at``: when to redraw without input (None: not at all)."""
        self.pending = max(self.pending - 1, 1 if changed else 0)
        self.wake_at = wake_at


def install_event_callbacks(window, on_event, routed: bool = False) -> None:
    """Call ``on_event`` on every glfw event of ``window`` (input, resize, expose, focus, drop); with ``routed``, on
    all but the pointer, buttons, keys and characters (which :func:`viewer.chords.install_ctrl_grace` routes).

    Must run before imgui's glfw backend installs its callbacks, which then chain to these.
    """
    import glfw

    inputs = (
        ()
        if routed
        else (
            glfw.set_cursor_pos_callback,
            glfw.set_mouse_button_callback,
            glfw.set_key_callback,
            glfw.set_char_callback,
        )
    )
    for setter in (
        *inputs,
        glfw.set_scroll_callback,
        glfw.set_cursor_enter_callback,
        glfw.set_window_focus_callback,
        glfw.set_window_size_callback,
        glfw.set_framebuffer_size_callback,
        glfw.set_window_refresh_callback,
        glfw.set_window_iconify_callback,
        glfw.set_drop_callback,
        glfw.set_window_close_callback,
    ):
        setter(window, on_event)
