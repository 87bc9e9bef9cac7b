"""`crowd-ik mouse` live: the planar chain and the humanoid posed by dragging in Taichi's GUI window."""

from __future__ import annotations

from collections import deque

import numpy as np

from crowd_ik.mouse.paths import Recorder
from crowd_ik.mouse.session import (
    HUMANOID_METHODS,
    KEYS,
    LEGEND,
    TRAIL_LENGTH,
    ChainSession,
)
from crowd_ik.mouse.view import (
    ChainPicture,
    View,
    draw_chain_frame,
)

# ---------------------------------------------------------------------------------------------
# live windows


def _to_px(pos, size) -> tuple[float, float]:
    """Taichi GUI position (x right, y up, 0..1) -> pixel coordinates (x right, y down)."""
    x, y = pos
    w, h = size
    return x * w, h - 1 - y * h


def live_chain(n_bones: int, method: str, limits: bool, size: tuple[int, int], record_dir=".") -> int:
    """The interactive window for the planar chain; returns 0 when closed (Esc or the window's X)."""
    import taichi as ti

    from crowd_ik.mouse.view import to_gui_image

    session = ChainSession(n_bones, method, limits)
    view = View(n_bones, *size)
    gui = ti.GUI("crowd-ik mouse", res=size)
    gui.fps_limit = 60
    recorder, dragging = None, False
    trail: deque = deque(maxlen=TRAIL_LENGTH)
    try:
        while gui.running:
            for e in gui.get_events(ti.GUI.PRESS, ti.GUI.RELEASE):
                key = e.key.lower() if isinstance(e.key, str) and len(e.key) == 1 else e.key
                if e.type == ti.GUI.RELEASE:
                    dragging = dragging and key != ti.GUI.LMB
                elif key == ti.GUI.ESCAPE:
                    gui.running = False
                elif key == ti.GUI.LMB:
                    dragging = True
                    session.target = view.to_world(*_to_px(e.pos, size))
                elif key in KEYS:
                    session.set_method(KEYS[key])
                elif key == "l":
                    session.toggle_limits()
                elif key == "r":
                    session.reset()
                    trail.clear()
                elif key == "c":
                    if recorder is None:
                        recorder = Recorder(record_dir)
                    else:
                        _save(recorder)
                        recorder = None
            if dragging:
                session.target = view.to_world(*_to_px(gui.get_cursor_pos(), size))
            session.step()
            if recorder is not None:
                recorder.add(session.target)
            joints = session.joints()
            trail.append(joints[-1])
            pic = ChainPicture(joints, session.target, session.lost, session.background(view), session.hud(), LEGEND,
                               np.array(trail), recording=recorder is not None)
            gui.set_image(to_gui_image(draw_chain_frame(view, pic)))
            gui.show()
    finally:
        if recorder is not None:
            _save(recorder)
        gui.close()
    return 0


def _save(recorder: Recorder) -> None:
    if recorder.rows:
        out = recorder.save()
        print(f"crowd-ik mouse: recorded {len(recorder.rows)} targets to {out}", flush=True)


def live_humanoid(method: str, size: tuple[int, int]) -> int:
    """The interactive window for the humanoid; returns 0 when closed."""
    import taichi as ti

    from crowd_ik.mouse.view import HumanoidSession, to_gui_image

    session = HumanoidSession(size, method)
    gui = ti.GUI("crowd-ik mouse (humanoid)", res=size)
    gui.fps_limit = 60
    keys = {k: m for k, m in KEYS.items() if m in HUMANOID_METHODS}
    try:
        while gui.running:
            for e in gui.get_events(ti.GUI.PRESS, ti.GUI.RELEASE):
                key = e.key.lower() if isinstance(e.key, str) and len(e.key) == 1 else e.key
                if e.type == ti.GUI.RELEASE:
                    if key == ti.GUI.LMB:
                        session.release()
                elif key == ti.GUI.ESCAPE:
                    gui.running = False
                elif key == ti.GUI.LMB:
                    session.press(*_to_px(e.pos, size))
                elif key in keys:
                    session.method = keys[key]
                elif key == "r":
                    session.reset()
            if session.active is not None:
                session.drag_to(*_to_px(gui.get_cursor_pos(), size))
            session.step()
            gui.set_image(to_gui_image(session.render()))
            gui.show()
    finally:
        gui.close()
    return 0
