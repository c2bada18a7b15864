"""Another robot in one tab's own scene: a student's run on a robot the class does not see.

    view = RunView(client, robots.load("so100"), frame_workspace(shared_arm), "your run: so100")
    view.set_controller(controller)     # the run's best network: the robot reaches for the goal with it
    view.remove()                       # the tab's camera frames the class's arm again

Everything is in client.scene under ROOT: only that tab has it. The robot stands beside the class's
arm, to its left (the panel is on the right of the page), drawn at the class's arm's size (an so100
next to the planar arm would otherwise be a speck: `placement`), on a floor grid of its own, with a
title ("your run: so100"), one goal marker per end effector that the student drags and a label with
the network's distance to the goal (in the robot's own units). Showing it frames the tab's camera on
both robots; removing it frames the class's arm again.
"""

from __future__ import annotations

import threading

import numpy as np

import robots
from lab.running.decimation import display_goal

from app.tab.scene import ArmView, frame_workspace, to_world

ROOT = "/tab/myrun"
GAP = 1.3  # the run's robot's centre, left of the class's, in the class's workspace sizes
# the camera on both: its aim, right of the class's centre, in workspace sizes, and how much farther back
LOOK, BACK = 0.0, 2.5


def placement(shared_ws: dict, ws: dict) -> tuple[float, np.ndarray]:
    """(scale, offset): the run's robot is drawn at offset + scale x its own coordinates, its workspace
    as large as the class's, its centre GAP sizes to the left of the class's centre, its floor on the
    class's."""
    scale = float(shared_ws["size"] / ws["size"])
    target = np.asarray(shared_ws["center"], float) - np.array([GAP * shared_ws["size"], 0.0, 0.0])
    offset = target - scale * np.asarray(ws["center"], float)
    offset[2] = shared_ws["floor_z"] - scale * ws["floor_z"]
    return scale, offset


class RunView:
    def __init__(self, client, arm: robots.Arm, shared_ws: dict, title: str):
        """client: the tab's ClientHandle; arm: the run's robot; shared_ws: frame_workspace of the arm the
        class sees (where this one stands beside it); title: the label above it."""
        self.client, self.arm, self.shared_ws = client, arm, shared_ws
        self.lock = threading.RLock()
        self.controller = None
        self.error = np.nan
        self.removed = False
        scene = client.scene
        self.ws = ws = frame_workspace(arm)
        self.scale, self.offset = s, o = placement(shared_ws, ws)
        size = ws["size"]
        center = o + s * np.asarray(ws["center"], float)
        self.floor = scene.add_grid(f"{ROOT}/floor", width=1.6 * size * s, height=1.6 * size * s,
                                    cell_size=ws["cell"] * s, section_size=10 * ws["cell"] * s,
                                    position=(center[0], center[1], o[2] + s * ws["floor_z"]))
        self.arm_view = ArmView(scene, arm, f"{ROOT}/arm", scale=s, offset=o)
        self.title = scene.add_label(f"{ROOT}/title", title, position=center + np.array([0.0, 0.0, 0.4 * size * s]),
                                     anchor="bottom-center")
        points = np.asarray(to_world(arm, display_goal(arm)), float).reshape(-1, 3)
        self.markers = [scene.add_transform_controls(
            f"{ROOT}/goal{e}", scale=ws["gizmo"] * s, position=o + s * p, disable_rotations=True,
            active_axes=tuple(k in arm.task_axes for k in range(3)),
            translation_limits=tuple((o[k] + s * a, o[k] + s * b) for k, (a, b) in enumerate(ws["limits"][e])),
            depth_test=False) for e, p in enumerate(points)]
        self.label = scene.add_label(f"{ROOT}/label", "", position=o + s * (points[0] + ws["label_offset"]),
                                     anchor="bottom-right")
        for marker in self.markers:
            marker.on_update(lambda _e: self.update())
        self.frame_camera()

    def to_world(self, goal) -> np.ndarray:
        """A goal in the robot's task coordinates -> where its marker stands in the tab's scene ((E, 3) on a tree)."""
        return self.offset + self.scale * np.asarray(to_world(self.arm, goal), float)

    @property
    def goal(self) -> np.ndarray:
        """The goal in the run's robot's task coordinates ((E, axes) on a tree), from its markers."""
        axes = list(self.arm.task_axes)
        local = (np.array([m.position for m in self.markers], float) - self.offset) / self.scale
        return local[0, axes] if len(self.markers) == 1 else local[:, axes]

    def answer(self) -> np.ndarray:
        """The joint angles the run's network gives for the goal (the rest pose without a network)."""
        if self.controller is None:
            return self.arm.rest
        return np.asarray(self.controller(self.goal[None])[0], float)

    def set_controller(self, controller) -> None:
        with self.lock:
            self.controller = controller
            self.update()

    def update(self) -> None:
        """The robot at the network's answer for the goal, the label its distance (the worst effector's)."""
        from app.tab.goals import fmt_len

        with self.lock:
            if self.removed:
                return
            goal = self.goal
            q = self.answer()
            self.error = (float(np.max(np.linalg.norm(np.atleast_2d(self.arm.reach(q) - goal), axis=-1)))
                          if self.controller is not None else np.nan)
            with self.client.atomic():
                self.arm_view.set_q(q)
                self.label.position = np.asarray(self.markers[0].position, float) + self.scale * self.ws["label_offset"]
                self.label.text = "no network yet" if self.controller is None else f"net {fmt_len(self.arm, self.error)}"
            self.client.flush()

    def frame_camera(self, both: bool = True) -> None:
        """The tab's camera on both robots (both) or on the class's arm alone."""
        shared = self.shared_ws
        view = np.asarray(shared["camera"], float) - np.asarray(shared["center"], float)
        center = np.asarray(shared["center"], float)
        if both:  # both in the page's left part (the panel covers its right): aimed right of their middle
            center = center + np.array([LOOK * shared["size"], 0.0, 0.0])
            view = view * BACK
        self.client.camera.look_at = center
        self.client.camera.position = center + view

    def remove(self) -> None:
        """Gone from the tab's scene; its camera on the class's arm again."""
        with self.lock:
            if self.removed:
                return
            self.removed = True
            self.arm_view.remove()
            for handle in (*self.markers, self.label, self.title, self.floor):
                handle.remove()
            self.frame_camera(both=False)
