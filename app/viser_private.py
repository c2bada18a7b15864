"""Every reach into viser's private API, in one place (tests/test_app.py checks each is still there).

viser 1.1 has no public way to do these; each has a measured reason, and a fallback to the
public API where one exists. When viser changes, `check()` names what is gone.
"""

from __future__ import annotations

import numpy as np

try:  # private: the scene's position and orientation messages
    from viser._messages import SetOrientationMessage, SetPositionMessage
except ImportError:  # pragma: no cover - another viser: set_pose falls back to the setters
    SetOrientationMessage = SetPositionMessage = None


def set_pose(handle, position: np.ndarray, wxyz: np.ndarray) -> None:
    """handle.position, handle.wxyz = position, wxyz, about 7x faster.

    Why: viser 1.1's pose setters cost about 0.3 ms per pose (casts, np.allclose, property
    machinery), which made arm updates the server's main cost while dragging. This queues the
    same two messages through the scene's own (private) queue and keeps the handle's state
    (`handle._impl`) in step; if that API is not there (another viser), it falls back to the setters."""
    impl = getattr(handle, "_impl", None)
    queue = getattr(getattr(impl, "api", None), "_queue_scene_message", None)
    if queue is None or SetPositionMessage is None or not hasattr(impl, "removed"):
        handle.position, handle.wxyz = position, wxyz
        return
    if impl.removed:  # a message for a removed node would bring it back in the browser
        return
    impl.position[:] = position
    impl.wxyz[:] = wxyz
    queue(SetPositionMessage(impl.name, (float(position[0]), float(position[1]), float(position[2]))))
    queue(SetOrientationMessage(impl.name, (float(wxyz[0]), float(wxyz[1]), float(wxyz[2]), float(wxyz[3]))))


def check(handle) -> list[str]:
    """What of the private API used here this viser lacks (empty: all there), for a scene handle."""
    missing = []
    if SetPositionMessage is None or SetOrientationMessage is None:
        missing.append("viser._messages.SetPositionMessage / SetOrientationMessage")
    impl = getattr(handle, "_impl", None)
    if impl is None:
        missing.append("SceneNodeHandle._impl")
    else:
        for name in ("removed", "name", "position", "wxyz"):
            if not hasattr(impl, name):
                missing.append(f"SceneNodeHandle._impl.{name}")
        if getattr(getattr(impl, "api", None), "_queue_scene_message", None) is None:
            missing.append("SceneApi._queue_scene_message")
    return missing
