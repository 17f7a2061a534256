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
        [sys.executable, "-m", "viewer", "--scene", str(demo_scenes()[0]), "--edits", str(edits)]
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


def test_a_ctrl_a_moment_late_still_counts(xdisplay, tmp_path):
    """Ctrl pressed a few ms after the key or the mouse button (within a frame), as a remote desktop or a quick hand
    sends it: S then Ctrl saves (Ctrl+S, not the S key's gizmo switch); a press on the selected object, a 20-pixel
    move up and then Ctrl lifts the object (a translate straight up) instead of sliding it on the floor."""
    import yaml

    from particlesplat.data.scene_meta import default_checkpoint
    from particlesplat.editing.open_scene import encode_scene
    from particlesplat.model import load_model
    from viewer.app import initial_view
    from viewer.orbit import OrbitCamera
    from viewer.session import EditableScene

    scene = demo_scenes()[0]
    model = load_model(default_checkpoint(scene))
    session = EditableScene(model, encode_scene(model, scene, [4, 16]), source=str(scene))
    ed = session.editor
    g = ed.decode()
    index = int(g.owner[g.owner >= 0][g.opacities[g.owner >= 0].argmax()])
    camera = OrbitCamera.from_view(initial_view(session, None, None)).camera(400, 300)
    (u, v), _ = (t[0] for t in camera.project(ed.object_centre(index)[None].to(camera.K.dtype)))
    env = {**os.environ, "DISPLAY": xdisplay}
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "viewer", "--scene", str(scene), "--context", "4,16", "--no-ui"]
        + ["--size", "400x300", "--output-dir", str(out)],
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

        def xdo(*args: str) -> None:
            subprocess.run(["xdotool", *args], env=env, check=True)

        xdo("keydown", "s", "keydown", "ctrl", "keyup", "s", "keyup", "ctrl")  # Ctrl a moment after S
        assert "saved 0 edit operation(s)" in _wait_for(lines, "saved ")
        x, y = round(float(u)), round(float(v))
        xdo("mousemove", "--window", wid, str(x), str(y), "click", "1")  # select the object
        time.sleep(1.0)
        xdo("mousedown", "1", "mousemove", "--window", wid, str(x), str(y - 20), "keydown", "ctrl")
        for k in range(1, 5):
            time.sleep(0.1)
            xdo("mousemove", "--window", wid, str(x), str(y - 20 - 10 * k))
        time.sleep(0.3)
        xdo("mouseup", "1", "keyup", "ctrl")
        time.sleep(0.5)
        xdo("key", "ctrl+s")
        line = _wait_for(lines, "saved ")
        assert "saved 1 edit operation(s)" in line, line
        saved = yaml.safe_load(next(out.glob("*.edits.yaml")).read_text())
        (op,) = saved["operations"]
        dx, dy, dz = op["translate"]
        assert dz > 0.01 and abs(dx) < 1e-6 and abs(dy) < 1e-6, op
    finally:
        proc.terminate()
        proc.wait(timeout=30)
