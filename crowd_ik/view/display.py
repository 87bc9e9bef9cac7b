"""Whether a window can open: an X server named by $DISPLAY that accepts a connection."""

from __future__ import annotations

import ctypes
import ctypes.util
import os


def display_available() -> bool:
    """True when $DISPLAY names an X server that accepts a connection."""
    name = os.environ.get("DISPLAY", "")
    if not name:
        return False
    lib = ctypes.util.find_library("X11")
    if lib is None:
        return True  # cannot check; let the window try
    x11 = ctypes.CDLL(lib)
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(name.encode())
    if not handle:
        return False
    x11.XCloseDisplay(handle)
    return True
