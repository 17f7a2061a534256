"""A Ctrl pressed within a frame after a key or a mouse press counts as held with it (:class:`viewer.chords.CtrlGrace`):
the events imgui gets, in order, on a fake clock. The real window, driven by xdotool: test_viewer_chords.py."""

from __future__ import annotations

import glfw
import pytest

from viewer.chords import HOLD_S, CtrlGrace

CTRL, A, S = glfw.KEY_LEFT_CONTROL, glfw.KEY_A, glfw.KEY_S
PRESS, RELEASE, MOD_CTRL, MOD_SHIFT = glfw.PRESS, glfw.RELEASE, glfw.MOD_CONTROL, glfw.MOD_SHIFT


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def grace():
    sent: list[tuple] = []
    clock = Clock()
    return CtrlGrace(sent.append, clock), sent, clock


def test_a_ctrl_just_after_a_key_makes_it_a_chord_that_types_nothing(grace):
    """A, its character, then Ctrl 5 ms later: imgui gets Ctrl first, then A with Ctrl, and no 'a'."""
    g, sent, clock = grace
    g.on_event(("key", A, 38, PRESS, 0))
    g.on_event(("char", ord("a")))
    assert sent == [] and g.due_in() == pytest.approx(HOLD_S)  # held, waiting for a Ctrl
    clock.now = 0.005
    g.on_event(("key", CTRL, 37, PRESS, MOD_CTRL))
    assert sent == [("key", CTRL, 37, PRESS, MOD_CTRL), ("key", A, 38, PRESS, MOD_CTRL)]
    g.on_event(("key", A, 38, RELEASE, MOD_CTRL))  # nothing held now: straight on
    assert sent[-1] == ("key", A, 38, RELEASE, MOD_CTRL) and g.due_in() is None


def test_a_key_without_a_ctrl_goes_on_as_it_came(grace):
    """No Ctrl within the hold: the key and its character go on in order once the time is up (not before); a key
    released before any Ctrl goes on at its release; Shift stays with it."""
    g, sent, clock = grace
    g.on_event(("key", A, 38, PRESS, MOD_SHIFT))
    g.on_event(("char", ord("A")))
    clock.now = HOLD_S / 2
    g.flush()
    assert sent == []
    clock.now = HOLD_S
    g.flush()
    assert sent == [("key", A, 38, PRESS, MOD_SHIFT), ("char", ord("A"))] and g.due_in() is None
    clock.now = 0.1  # a Ctrl later than the hold is a Ctrl of its own
    g.on_event(("key", CTRL, 37, PRESS, MOD_CTRL))
    assert sent[-1] == ("key", CTRL, 37, PRESS, MOD_CTRL) and len(sent) == 3
    sent.clear()
    g.on_event(("key", CTRL, 37, RELEASE, 0))
    g.on_event(("key", S, 39, PRESS, 0))
    g.on_event(("char", ord("s")))
    g.on_event(("key", S, 39, RELEASE, 0))  # released within the hold: no Ctrl meant
    assert sent == [("key", CTRL, 37, RELEASE, 0), ("key", S, 39, PRESS, 0), ("char", ord("s")),
                    ("key", S, 39, RELEASE, 0)]  # fmt: skip


def test_a_ctrl_just_after_a_mouse_press_holds_for_the_drag(grace):
    """Mouse press, a pointer motion, then Ctrl: Ctrl first, then the motion and the press with Ctrl, in order;
    a press with Ctrl held already, and a key with Ctrl, are not held."""
    g, sent, clock = grace
    g.on_event(("pos", 10.0, 10.0))
    g.on_event(("button", 0, PRESS, 0))
    g.on_event(("pos", 10.0, 12.0))
    clock.now = 0.012
    g.on_event(("key", CTRL, 37, PRESS, MOD_CTRL))
    assert sent == [("pos", 10.0, 10.0), ("key", CTRL, 37, PRESS, MOD_CTRL), ("button", 0, PRESS, MOD_CTRL),
                    ("pos", 10.0, 12.0)]  # fmt: skip
    sent.clear()
    g.on_event(("button", 0, RELEASE, MOD_CTRL))
    g.on_event(("button", 0, PRESS, MOD_CTRL))
    g.on_event(("key", A, 38, PRESS, MOD_CTRL))
    assert len(sent) == 3 and g.due_in() is None
    g.flush(force=True)
    assert len(sent) == 3
