"""Driving a real window in tests: an Xvfb display, xdotool, and a crowd-ik window process."""

import os
import shutil
import subprocess
import sys
import time
from contextlib import contextmanager

import pytest


def xdo(display: str, *args: str) -> str:
    """Run xdotool on `display` and return its stdout."""
    out = subprocess.run(["xdotool", *args], env=dict(os.environ, DISPLAY=display), capture_output=True,
                         text=True, timeout=20)
    return out.stdout


@contextmanager
def crowd_ik_window(argv: list[str], title: str, cwd):
    """Start `python -m crowd_ik ARGV` on a fresh Xvfb display; yield (app, display, window id).

    Skips the test where Xvfb or xdotool is missing; kills the app and the display afterwards.
    """
    if not (shutil.which("Xvfb") and shutil.which("xdotool")):
        pytest.skip("needs Xvfb and xdotool (apt-get install xvfb xdotool)")
    r, w = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "640x480x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    app = None
    try:
        with os.fdopen(r) as fh:
            display = ":" + fh.readline().strip()
        env = dict(os.environ, DISPLAY=display)
        win, why = "", ""
        for _ in range(3):  # a fresh Xvfb now and then refuses the first GLX window under load: start again
            app = subprocess.Popen([sys.executable, "-m", "crowd_ik", *argv], cwd=cwd, env=env,
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            deadline = time.monotonic() + 90
            while not win and time.monotonic() < deadline and app.poll() is None:
                time.sleep(0.3)
                win = xdo(display, "search", "--name", title).split("\n")[0].strip()
            if win:
                break
            why = f"{app.poll()} {app.stderr.read() if app.poll() is not None else ''}"
            if app.poll() is None or "fails to create a window" not in why:
                break
            time.sleep(1.0)
        assert win, f"no window appeared: {why}"
        time.sleep(1.5)
        yield app, display, win
    finally:
        if app is not None and app.poll() is None:
            app.kill()
            app.wait()
        xvfb.terminate()
        xvfb.wait(timeout=10)
