"""A phone's tab: the panel folded to its bar, so that the arm is in view; a tap on the bar opens it;
and on a page taller than wide the camera drawn back, so that the whole workspace is in view.

viser 1.1.1 lays a narrow page out as a bottom sheet (its client's ControlPanel/BottomPanel.tsx,
below the theme's `xs` breakpoint, 36em): the lab's whole panel at the bottom right, up to 60 % of
the page's height, over the scene, and open when the page loads. Nothing on the server folds it:
`gui.main_panel.minimize()` and `configure_theme(control_layout=...)` act on the desktop's dock
only (the sheet keeps its open state in the page), and `control_width` does not change the sheet's
width (20em). So each tab gets `fold_on_phone(client.gui, label)`: an HTML element of no size whose
image fails to load at once and, on a page as narrow as viser's mobile breakpoint, clicks the
sheet's bar once (the bar is the element before the sheet's contents that carries the panel's
label). A wider page, a tab that already folded it (the sheet re-mounts its contents when it
opens again) or another layout of viser's client: nothing happens, the panel stays as it was.
This is the one place that relies on the layout of viser's client page; tests/test_app_phone.py
holds it to viser's page in a real browser.
"""

from __future__ import annotations

import html

import numpy as np

# a canvas narrower than PORTRAIT (width / height) sees less of the workspace across than the
# framing (app/tab/scene.py frame_workspace, made for a landscape page) assumes: the camera is drawn back
# along its line of sight by PORTRAIT / aspect, at most MAX_PULL times
PORTRAIT = 0.8
MAX_PULL = 2.5
MOBILE_WIDTH = "36em"  # viser's mobile breakpoint (Mantine's `xs`): narrower pages get the bottom sheet

_SCRIPT = (
    "if(!window.__labFolded&&matchMedia('(max-width: " + MOBILE_WIDTH + ")').matches){"
    "window.__labFolded=1;"
    "for(var e=this;e;e=e.parentElement){var b=e.previousElementSibling;"
    "if(b&&getComputedStyle(b).cursor==='pointer'&&b.textContent.indexOf(LABEL)>=0){b.click();break;}}}"
)


def fold_html(label: str) -> str:
    """The element that folds a phone's panel (label: the panel's label, set_panel_label)."""
    script = _SCRIPT.replace("LABEL", repr(str(label)))
    return f'<img alt="" src="data:," style="display:none" onerror="{html.escape(script, quote=True)}">'


def fold_on_phone(gui, label: str, order: float = -10.0):
    """Add the folding element to a tab's own panel (client.gui); its handle."""
    return gui.add_html(fold_html(label), order=order)


def portrait_distance(aspect: float) -> float:
    """How many times farther from the workspace's centre the camera goes on a canvas of this aspect."""
    return float(np.clip(PORTRAIT / aspect, 1.0, MAX_PULL)) if aspect > 0 else 1.0


def follow_portrait(client, framing) -> None:
    """On a canvas taller than wide, draw the tab's camera back from the arm's framing (framing(): the
    tab's frame_workspace dict), each time the camera is where that framing put it (a new tab, another
    arm); a camera the visitor has moved is left alone."""

    def on_camera(camera) -> None:
        try:
            aspect = camera.aspect
        except (AssertionError, ZeroDivisionError):  # no size reported yet
            return
        k = portrait_distance(aspect)
        if k == 1.0:
            return
        ws = framing()
        framed, center = np.asarray(ws["camera"], float), np.asarray(ws["center"], float)
        if np.linalg.norm(np.asarray(camera.position) - framed) > 1e-3 * ws["size"]:
            return
        camera.position = center + k * (framed - center)

    client.camera.on_update(on_camera)
