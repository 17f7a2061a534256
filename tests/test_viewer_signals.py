"""SIGINT, SIGTERM and SIGHUP end the viewer as closing its window does, in a real window (CI runs pytest under
xvfb-run): one line and exit code 128 + the signal. The test waits for the viewer to say it is ready and starts it
with SIGINT ignored, as a shell starts a background job, so it holds however the suite is started. The one second
when idle and the autosave are held in process (tests/test_viewer_app.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from viewer.bench.random_gaussians import random_gaussians

pytestmark = pytest.mark.window

VIEWER = str(Path(sys.executable).with_name("particlesplat-viewer"))


def _ignore_sigint() -> None:  # as a shell starts a background job: the worst case for Ctrl-C
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["INT", "TERM", "HUP"])
def test_a_signal_ends_the_idle_viewer_with_one_line(tmp_path, sig):
    if not os.environ.get("DISPLAY"):
        pytest.fail("no DISPLAY: run the tests under xvfb-run (see the README's test command)")
    random_gaussians(200, seed=1).save_ply(tmp_path / "g.ply")
    proc = subprocess.Popen(
        [VIEWER, "--ply", str(tmp_path / "g.ply"), "--size", "160x120", "--output-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_ignore_sigint,
    )
    try:
        line = proc.stdout.readline()  # printed once the window is up and the handlers are in place
        assert "close the window or press Ctrl-C" in line, line + proc.stderr.read()
        time.sleep(0.5)  # idle: the loop sleeps in glfw.wait_events() (nothing to draw)
        t0 = time.perf_counter()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
        elapsed = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + sig, err
    assert err == f"particlesplat-viewer: interrupted ({signal.Signals(sig).name})\n"
    assert elapsed < 10.0  # the idle loop woke (test_viewer_app holds the one second)
