"""A phone's camera (app/tab/phone.py), without a browser: on a canvas as narrow as viser's mobile
layout the arm's workspace is framed above the opened sheet, whole; a portrait page that is not a
phone's keeps the drawn-back framing; a camera the visitor moved is left alone. The page itself is
checked in a real browser in tests/test_app_browser_layout.py."""

from __future__ import annotations

import numpy as np
import pytest

import robots
from app.tab import phone
from app.tab.scene import frame_workspace

FOV = np.deg2rad(75.0)  # viser's default
UP = np.array([0.0, 0.0, 1.0])


def project(position, look_at, up, fov, aspect, points) -> np.ndarray:
    """Normalised device coordinates (x right, y up, each -1..1 on the page) of world points."""
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    rel = np.atleast_2d(points) - position
    depth = rel @ forward
    t = np.tan(0.5 * fov)
    return np.stack([(rel @ right) / (depth * t * aspect), (rel @ true_up) / (depth * t)], axis=1)


def sphere(center, radius, n=400) -> np.ndarray:
    k = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * k / n), np.pi * (1 + 5 ** 0.5) * k
    return center + radius * np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


@pytest.mark.parametrize("robot", ["planar", "ur5", "g1"])
def test_a_phone_sees_the_whole_workspace_above_the_opened_sheet(robot):
    ws = frame_workspace(robots.load(robot))
    aspect = 390 / 844
    position, look_at = phone.phone_view(ws, aspect, FOV, UP)
    ndc = project(position, look_at, UP, FOV, aspect, sphere(ws["center"], 0.5 * ws["size"]))
    sheet_top = 1 - 2 * (1 - phone.SHEET)  # the sheet covers the page below this (NDC y)
    assert ndc[:, 1].min() > sheet_top, (ndc[:, 1].min(), sheet_top)  # the whole workspace above the sheet
    assert np.abs(ndc).max() < 1.0  # and within the page
    centre = project(position, look_at, UP, FOV, aspect, ws["center"])[0]
    assert centre[1] > 0.25 and abs(centre[0]) < 1e-9  # in the upper part, across the middle
    # seen along the framing's own line of sight, no nearer than it
    assert np.allclose((look_at - position) / np.linalg.norm(look_at - position),
                       (ws["center"] - ws["camera"]) / np.linalg.norm(ws["center"] - ws["camera"]))
    assert np.linalg.norm(look_at - position) >= np.linalg.norm(ws["center"] - ws["camera"]) - 1e-9


class FakeCamera:
    def __init__(self, width, height, position):
        self.image_width, self.image_height, self.aspect = width, height, width / height
        self.fov, self.up_direction = FOV, UP
        self.position, self.look_at = np.asarray(position, float), None


class FakeClient:
    def __init__(self, camera):
        self.camera = camera
        self.camera.on_update = lambda f: setattr(self, "callback", f)


@pytest.mark.parametrize("width, height, framed_as", [(390, 844, "phone"), (800, 1200, "drawn back"),
                                                       (1366, 768, "as framed")])
def test_only_a_phones_canvas_is_framed_above_the_sheet(width, height, framed_as):
    ws = frame_workspace(robots.load("planar"))
    client = FakeClient(FakeCamera(width, height, ws["camera"]))
    phone.follow_portrait(client, lambda: ws)
    client.callback(client.camera)
    want = {"phone": phone.phone_view(ws, width / height, FOV, UP)[0],
            "drawn back": ws["center"] + phone.portrait_distance(width / height) * (ws["camera"] - ws["center"]),
            "as framed": ws["camera"]}[framed_as]
    assert np.allclose(client.camera.position, want)
    moved = client.camera.position + 5.0  # the visitor's own view: left alone
    client.camera.position = moved
    client.callback(client.camera)
    assert np.allclose(client.camera.position, moved)


def test_the_fold_element_caps_the_sheets_height():
    html = phone.fold_html("Neuro-IK Lab")
    assert f"max-height&#x27;,&#x27;{phone.SHEET * 100:g}%" in html and "Neuro-IK Lab" in html
