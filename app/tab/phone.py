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
The same element caps the sheet's height at SHEET of the page (viser's: 60 %), each time it opens;
and on a page as narrow as a phone's, the camera frames the arm in the part of the page above it
(`phone_view`), so that the opened panel leaves the arm in view.
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
MOBILE_PX = 576  # the same in CSS pixels (16 px to the em): a canvas this narrow is a phone's
SHEET = 0.45  # the opened sheet's height at most, a fraction of the page's: the arm above it
FILL = 0.85  # of the free part's shorter side, the workspace's extent in a phone's framing

_SCRIPT = (
    "if(matchMedia('(max-width: " + MOBILE_WIDTH + ")').matches){"
    "for(var e=this;e;e=e.parentElement){var b=e.previousElementSibling;"
    "if(b&&getComputedStyle(b).cursor==='pointer'&&b.textContent.indexOf(LABEL)>=0){"
    "for(var s=b;s;s=s.parentElement){if(getComputedStyle(s).position==='fixed'){"
    "s.style.setProperty('max-height','" + f"{SHEET * 100:g}" + "%','important');break;}}"
    "if(!window.__labFolded){window.__labFolded=1;b.click();}break;}}}"
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


def phone_view(ws: dict, aspect: float, fov: float, up) -> tuple[np.ndarray, np.ndarray]:
    """(position, look_at) of a phone's camera: the workspace (frame_workspace's dict: its centre,
    size, and the camera's direction of view) seen along the same line of sight, FILL of the
    shorter side of the part of the page above the opened sheet (the top 1 - SHEET), centred there.
    aspect: the canvas's width / height; fov: its vertical field of view (radians); up: the
    camera's up direction."""
    center, framed = np.asarray(ws["center"], float), np.asarray(ws["camera"], float)
    view = (center - framed) / np.linalg.norm(center - framed)
    up = np.asarray(up, float)
    screen_up = up - (up @ view) * view
    if np.linalg.norm(screen_up) < 1e-9:  # looking straight down the up direction: any perpendicular
        screen_up = np.cross(view, [1.0, 0.0, 0.0] if abs(view[0]) < 0.9 else [0.0, 1.0, 0.0])
    screen_up /= np.linalg.norm(screen_up)
    tan = np.tan(0.5 * fov)
    free = min(aspect, 1.0 - SHEET)  # the free part's shorter side, in page heights
    distance = max(ws["size"] / (2.0 * tan * FILL * free), float(np.linalg.norm(center - framed)))
    look_at = center - screen_up * (SHEET * distance * tan)  # the centre SHEET of a half-height above the page's
    return look_at - view * distance, look_at


def is_phone(camera) -> bool:
    """A canvas as narrow as viser's mobile breakpoint (its panel a bottom sheet) and taller than wide."""
    return 0 < camera.image_width <= MOBILE_PX and camera.aspect < PORTRAIT


def follow_portrait(client, framing) -> None:
    """On a canvas taller than wide, draw the tab's camera back from the arm's framing (framing(): the
    tab's frame_workspace dict), each time the camera is where that framing put it (a new tab, another
    arm); on a phone's (is_phone), frame the arm above the opened sheet instead (phone_view). A
    camera the visitor has moved is left alone."""

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
        if is_phone(camera):
            position, look_at = phone_view(ws, aspect, camera.fov, camera.up_direction)
            camera.position = position
            camera.look_at = look_at
            return
        camera.position = center + k * (framed - center)

    client.camera.on_update(on_camera)
