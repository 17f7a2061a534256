"""Ctrl as the user meant it, however fast it came.

- Ctrl chords (Ctrl+Z, Ctrl+Shift+Z, Ctrl+Y, Ctrl+S, Ctrl+D) are taken from glfw's key callback with the modifiers
  that came with the key event, not from the modifier state polled later (:class:`ChordQueue`): a fast chord
  (``xdotool key ctrl+z``, remote desktops, scripted input: Ctrl released within a few ms of the key) is still a
  chord when the frame reads it.
- A Ctrl pressed just after a key or a mouse button, within :data:`HOLD_S` (a frame), counts as held with it
  (:class:`CtrlGrace`): a plain key or mouse press waits that long before imgui sees it; a Ctrl press in that time
  goes first and the press follows as a Ctrl press (Ctrl+A selects a text field's text instead of typing ``a``;
  Ctrl + drag lifts the object instead of sliding it).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import glfw

CHORD_KEYS = {glfw.KEY_Z: "z", glfw.KEY_Y: "y", glfw.KEY_S: "s", glfw.KEY_D: "d"}
MAX_QUEUED = 64  # chords kept between two frames (more is a stuck key)
HOLD_S = 0.02  # seconds a plain key or mouse press waits for a Ctrl that follows it (a frame at 50 Hz)
CTRL_KEYS = (glfw.KEY_LEFT_CONTROL, glfw.KEY_RIGHT_CONTROL)
MODIFIER_KEYS = (
    *CTRL_KEYS,
    glfw.KEY_LEFT_SHIFT,
    glfw.KEY_RIGHT_SHIFT,
    glfw.KEY_LEFT_ALT,
    glfw.KEY_RIGHT_ALT,
    glfw.KEY_LEFT_SUPER,
    glfw.KEY_RIGHT_SUPER,
)


@dataclass
class ChordQueue:
    """Chords pressed since the frame last took them: ("z", shift held) per press (key repeats of z and y too)."""

    chords: deque = field(default_factory=lambda: deque(maxlen=MAX_QUEUED))

    def on_key(self, _window, key: int, _scancode: int, action: int, mods: int) -> None:
        """A glfw key callback: a press (or a repeat of Z / Y, which undo and redo while held) with Ctrl in
        ``mods``."""
        if not mods & glfw.MOD_CONTROL or key not in CHORD_KEYS:
            return
        if action == glfw.PRESS or (action == glfw.REPEAT and key in (glfw.KEY_Z, glfw.KEY_Y)):
            self.chords.append((CHORD_KEYS[key], bool(mods & glfw.MOD_SHIFT)))

    def take(self) -> list[tuple[str, bool]]:
        """The chords since the last call, oldest first."""
        out = list(self.chords)
        self.chords.clear()
        return out


# an input event as a glfw callback got it: ("key", key, scancode, action, mods), ("char", codepoint),
# ("button", button, action, mods) or ("pos", x, y)
Event = tuple
Forward = Callable[[Event], None]


@dataclass
class CtrlGrace:
    """Routes a window's key, character, mouse button and pointer events to imgui (``forward``, in order), holding a
    plain key or mouse press for :data:`HOLD_S`: a Ctrl press in that time is sent first, then the held events with
    Ctrl added to the presses' modifiers and their typed characters dropped (a chord types nothing). Held events go
    on as they came once their time is up (:meth:`flush`, each frame) or when the press they wait on is released.

    Attributes:
        forward: sends one event on (to imgui's glfw callbacks, which chain to the viewer's).
        clock: seconds (``time.perf_counter``).
    """

    forward: Forward
    clock: Callable[[], float] = time.perf_counter
    held: list[Event] = field(default_factory=list)
    since: float | None = None  # when the held press came

    def on_event(self, event: Event) -> None:
        """One event from glfw (see :data:`Event`)."""
        kind = event[0]
        if kind == "key" and event[1] in CTRL_KEYS and event[3] == glfw.PRESS:
            self._ctrl(event)
            return
        if self.held:
            self.held.append(event)
            if self._releases_held(event):
                self._send_held()
            return
        if self._plain_press(event):
            self.held, self.since = [event], self.clock()
            return
        self.forward(event)

    def flush(self, force: bool = False) -> None:
        """Send the held events on once :data:`HOLD_S` passed since the press (or now, with ``force``)."""
        if self.held and self.since is not None and (force or self.clock() - self.since >= HOLD_S):
            self._send_held()

    def due_in(self) -> float | None:
        """Seconds until the held events go on (0: now), or None when nothing is held."""
        if not self.held or self.since is None:
            return None
        return max(0.0, HOLD_S - (self.clock() - self.since))

    @staticmethod
    def _plain_press(event: Event) -> bool:
        """A key press (not a modifier key) or a mouse button press without Ctrl."""
        if event[0] == "key":
            return event[3] == glfw.PRESS and event[1] not in MODIFIER_KEYS and not event[4] & glfw.MOD_CONTROL
        return event[0] == "button" and event[2] == glfw.PRESS and not event[3] & glfw.MOD_CONTROL

    def _releases_held(self, event: Event) -> bool:
        """Whether ``event`` releases the held press (the key or button let go before any Ctrl)."""
        first = self.held[0]
        if first[0] == "key" and event[0] == "key":
            return event[1] == first[1] and event[3] == glfw.RELEASE
        return first[0] == "button" and event[0] == "button" and event[1] == first[1] and event[2] == glfw.RELEASE

    def _ctrl(self, event: Event) -> None:
        """A Ctrl press: first, then what was held, as pressed with Ctrl."""
        held, self.held, self.since = self.held, [], None
        self.forward(event)
        for e in held:
            if e[0] == "char":
                continue  # typed because Ctrl came a moment late: a chord types nothing
            if e[0] == "key":
                e = (*e[:4], e[4] | glfw.MOD_CONTROL)
            elif e[0] == "button":
                e = (*e[:3], e[3] | glfw.MOD_CONTROL)
            self.forward(e)

    def _send_held(self) -> None:
        held, self.held, self.since = self.held, [], None
        for e in held:
            self.forward(e)


def install_ctrl_grace(
    window, window_address: int, on_event: Callable[[], None], on_key: Callable[..., None]
) -> CtrlGrace:
    """Route ``window``'s key, character, mouse button and pointer events through a :class:`CtrlGrace` to imgui's
    glfw callbacks (imgui's backend installed already, with nothing of the viewer's for these events to chain to);
    ``on_event`` runs on every event as it comes (the redraw schedule: the loop wakes to pass a held press on in
    time), ``on_key`` (a glfw key callback: :meth:`ChordQueue.on_key`) on every key event as it goes on to imgui,
    with the modifiers it goes with. Returns the router: the frame loop calls its :meth:`CtrlGrace.flush` before
    each frame and waits no longer than :meth:`CtrlGrace.due_in`."""
    from imgui_bundle.imgui import backends

    def forward(event: Event) -> None:
        kind, *args = event
        if kind == "key":
            backends.glfw_key_callback(window_address, *args)
            on_key(window, *args)
        elif kind == "char":
            backends.glfw_char_callback(window_address, *args)
        elif kind == "button":
            backends.glfw_mouse_button_callback(window_address, *args)
        else:
            backends.glfw_cursor_pos_callback(window_address, *args)

    grace = CtrlGrace(forward)

    def route(kind: str) -> Callable:
        def callback(_window, *args) -> None:
            on_event()
            grace.on_event((kind, *args))

        return callback

    glfw.set_key_callback(window, route("key"))
    glfw.set_char_callback(window, route("char"))
    glfw.set_mouse_button_callback(window, route("button"))
    glfw.set_cursor_pos_callback(window, route("pos"))
    return grace
