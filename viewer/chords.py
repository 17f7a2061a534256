"""Ctrl chords (Ctrl+Z, Ctrl+Shift+Z, Ctrl+Y, Ctrl+S, Ctrl+D) taken from glfw's key callback with the modifiers that
came with the key event, not from the modifier state polled later: a fast chord (``xdotool key ctrl+z``, remote
desktops, scripted input: Ctrl released within a few ms of the key) is still a chord when the frame reads it."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import glfw

CHORD_KEYS = {glfw.KEY_Z: "z", glfw.KEY_Y: "y", glfw.KEY_S: "s", glfw.KEY_D: "d"}
MAX_QUEUED = 64  # chords kept between two frames (more is a stuck key)


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
