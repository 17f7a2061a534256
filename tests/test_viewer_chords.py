"""Fast Ctrl chords in a real window: ``xdotool key ctrl+s`` and ``ctrl+z`` (each key held ~12 ms, Ctrl released
right after, as remote desktops and scripted input send them) are each taken once, with the modifiers their key
events carried. The viewer runs from this checkout under its own Xvfb display; its status lines are mirrored on the
terminal, which is what the test reads."""

from __future__ import annotations

import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from particlesplat.editing.open_scene import demo_scenes

pytestmark = pytest.mark.window

ROOT = Path(__file__).resolve().parents[1]


def _free_display() -> int:
    n = 90
    while Path(f"/tmp/.X11-unix/X{n}").exists() or Path(f"/tmp/.X{n}-lock").exists():
        n += 1
    return n


@pytest.fixture
def xdisplay():
    if shutil.which("Xvfb") is None or shutil.which("xdotool") is None:
        pytest.skip("fast-chord test needs Xvfb and xdotool (apt-get install xvfb xdotool)")
    n = _free_display()
    server = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", "800x600x24", "-nolisten", "tcp"])
    deadline = time.time() + 20
    while not Path(f"/tmp/.X11-unix/X{n}").exists() and time.time() < deadline:
        time.sleep(0.05)
    yield f":{n}"
    server.terminate()
    server.wait(timeout=10)


def _lines(stream, out: queue.Queue) -> None:
    for line in stream:
        out.put(line)


def _wait_for(lines: queue.Queue, text: str, timeout: float = 120.0) -> str:
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        if text in line:
            return line
    raise AssertionError(f"no line with {text!r} within {timeout} s")


def test_fast_ctrl_chords_are_taken(xdisplay, tmp_path):
    env = {**os.environ, "DISPLAY": xdisplay}
    edits = tmp_path / "e.yaml"  # one operation to undo: a version 1 file sets particle 0's depth
    edits.write_text("version: 1\nparticles:\n  0:\n    z_d: [0.5]\n")
    proc = subprocess.Popen(
        [sys.executable, "-m", "viewer.app", "--scene", str(demo_scenes()[0]), "--edits", str(edits)]
        + ["--size", "400x300", "--output-dir", str(tmp_path / "out")],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(proc.stdout, lines), daemon=True).start()
    try:
        _wait_for(lines, "close the window or press Ctrl-C")
        wid = subprocess.run(
            ["xdotool", "search", "--sync", "--name", "ParticleSplat Studio"], env=env, capture_output=True, text=True
        ).stdout.split()[0]
        subprocess.run(["xdotool", "windowfocus", "--sync", wid], env=env, check=True)
        time.sleep(0.5)

        def key(chord: str) -> None:
            subprocess.run(["xdotool", "key", *chord.split()], env=env, check=True)  # 12 ms a key, xdotool's default

        key("ctrl+s")
        assert "saved 1 edit operation(s)" in _wait_for(lines, "saved ")
        key("ctrl+z ctrl+s")  # two chords 12 ms apart, in one burst of events
        assert "saved 0 edit operation(s)" in _wait_for(lines, "saved ")
        key("ctrl+shift+z ctrl+s")
        assert "saved 1 edit operation(s)" in _wait_for(lines, "saved ")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
