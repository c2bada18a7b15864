"""Robots outside the registry in the app: any string `robots.load` takes (erd:NAME, a URDF path).

    choices(state)            # the Robot menus: the registered robots, then those opened since the server started
    capsules(arm)             # what to draw where a chain link has nothing to draw (no visual, no mesh)
    page_note(arm)            # a line for the page: the frame picked, the links drawn as capsules
    identity(robot)           # {"robot": string, "urdf_sha256": ...}: a run's robot in the notebook
    replay_note(robot, sha)   # None, or what a replay must say: the URDF changed or is gone
    MoreRobots(gui, open_robot, ...)   # the Train panel's "More robots…": example-robot-data, a URDF upload

An unknown robot has no shipped controller (app/pretrained/ holds the registered arms'): the app
opens it at rest with NO_NETWORK as the network's source, and Start trains one. A chain link whose
URDF gives it no visual, or whose mesh does not resolve (arm.missing_meshes), is drawn as a capsule
from its joint to the next joint (or the tool frame), said once in the log and on the page.
"""

from __future__ import annotations

import logging
import os
import threading

import numpy as np

import robots
from app.classroom.uploads import MAX_URDF
from robots.visual import undrawn_joints

log = logging.getLogger(__name__)

MORE = "More robots…"  # the Robot menu's last entry: unfolds the "More robots…" folder
NO_NETWORK = "no trained network yet for this robot: press Start to train one"
_said: set[str] = set()  # arms whose capsules the log has named (once per arm per process)


def registered(name: str) -> bool:
    return name in robots.names()


def choices(state, more: bool = False) -> tuple[str, ...]:
    """The Robot menu: the registered robots, then every robot opened since the server started (state.opened_robots),
    then MORE (the presenter's menu)."""
    names = list(robots.names())
    names += [n for n in getattr(state, "opened_robots", ()) if n not in names]
    return tuple(names) + ((MORE,) if more else ())


# ---------------------------------------------------------------- drawing
def capsules(arm: robots.Arm) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """(joint index, start, end) in that joint's frame, one per segment a viewer draws as a capsule: from
    each undrawn chain joint's origin to its next chain joint's (or the tool frame's); a joint with no
    joint or frame after it gets a point (start == end)."""
    model = arm.model
    names = set(undrawn_joints(arm))
    chain = {int(j) for j in arm.chain.joint_ids}
    effectors = set(getattr(arm, "effectors", ()) or (arm.ee_frame,))
    out = []
    for j in range(1, model.njoints):
        if model.names[j] not in names:
            continue
        ends = [np.array(model.jointPlacements[k].translation) for k in range(1, model.njoints)
                if int(model.parents[k]) == j and k in chain]
        ends += [np.array(f.placement.translation) for f in model.frames
                 if int(f.parentJoint) == j and f.name in effectors]
        for end in ends or [np.zeros(3)]:
            out.append((j, np.zeros(3), end))
    return out


def capsule_radius(arm: robots.Arm) -> float:
    return 0.025 * float(arm.reach_radius)


def capsule_note(arm: robots.Arm) -> str | None:
    """The sentence naming the links drawn as capsules (None: every chain link has its own drawing);
    logged once per arm."""
    joints = undrawn_joints(arm)
    if not joints:
        return None
    missing = list(getattr(arm, "missing_meshes", ()) or ())
    text = (f"drawn as capsules between joint origins (no visual, or no mesh that resolves): the links moved by "
            f"{', '.join(joints)}")
    if missing:
        text += f"; meshes not found for {', '.join(missing[:8])}{' …' if len(missing) > 8 else ''}"
    if arm.name not in _said:
        _said.add(arm.name)
        log.warning("%s: %s", arm.name, text)
    return text


def page_note(arm: robots.Arm) -> str:
    """A robot outside the registry, in a few words for the Train panel ("" for a registered one)."""
    if registered(arm.name):
        return ""
    frames = ", ".join(f"`{f}`" for f in (getattr(arm, "effectors", ()) or (arm.ee_frame,)))
    sha = getattr(arm, "urdf_sha256", None)
    text = (f"**{arm.name}**: a robot of your own, {arm.nq} joints, tool frame {frames} (pick another with "
            f"`--ee` or `#frame`){f', URDF sha256 {sha[:12]}…' if sha else ''}. The lab ships no network for it: "
            "press Start to train one.")
    note = capsule_note(arm)
    return text + (f"  \nLinks {note}." if note else "")


# ---------------------------------------------------------------- identity
def identity(robot: str) -> dict:
    """{"robot": the string, "urdf_sha256": its URDF's sha256 (None when it cannot be loaded)}."""
    try:
        sha = robots.load(robot).urdf_sha256
    except Exception:  # noqa: BLE001 - a run's entry is kept whatever its robot
        sha = None
    return {"robot": robot, "urdf_sha256": sha}


def replay_note(robot: str, sha256: str | None) -> str | None:
    """What opening a run of `robot` must say about its URDF: None when it is the file the run used (or the
    run recorded no sha256: runs of earlier versions), else that it changed or is gone."""
    if not isinstance(sha256, str) or not sha256:
        return None
    status = robots.source_status(robot, sha256)
    if status == "unchanged":
        return None
    if status == "gone":
        return (f"the URDF of this run's robot {robot} is gone (it was sha256 {sha256[:12]}…); the run stays listed, "
                "its numbers in the notebook")
    return (f"the URDF of this run's robot {robot} has changed since the run (it was sha256 {sha256[:12]}…): "
            "the network was trained on the file as it was")


# ---------------------------------------------------------------- the menu
def erd_names() -> tuple[str, ...]:
    try:
        import example_robot_data as erd
    except ImportError:
        return ()
    return tuple(sorted(erd.ROBOTS))


class MoreRobots:
    """The Train panel's "More robots…" folder: any example-robot-data robot, or an uploaded URDF, opened
    (robots.load in a thread of its own: the render loop goes on) by open_robot(name) -> None or the
    refusal (the app's switch_robot). A robot load refuses is named in the folder with the reason."""

    def __init__(self, gui, open_robot, notify=None):
        import viser

        self.open_robot, self.notify = open_robot, notify
        self.upload_folder: str | None = None  # set by the app (its recordings' uploads/)
        self.guard = None  # the app's UploadGuard: .done() when an upload is handled
        self._busy = threading.Lock()
        self.folder = gui.add_folder(MORE, expand_by_default=True, visible=False)
        names = erd_names()
        with self.folder:
            self.erd = gui.add_dropdown("example-robot-data", names or ("(not installed)",),
                                        initial_value=("ur5" if "ur5" in names else (names or ("(not installed)",))[0]),
                                        hint="every robot the example-robot-data package ships, opened as erd:NAME")
            self.open_button = gui.add_button("Open this robot", icon=viser.Icon.FOLDER_OPEN)
            self.upload = gui.add_upload_button("Upload a URDF (.urdf)", icon=viser.Icon.UPLOAD, mime_type="*/*",
                                                hint="one URDF file, no meshes needed: links without one are drawn "
                                                     "as capsules")
            self.message = gui.add_markdown("")
        self.open_button.on_click(lambda e: self.open("erd:" + self.erd.value, e.client))
        self.upload.on_upload(self._on_upload)

    def show(self) -> None:
        self.folder.visible = True

    def _say(self, text: str, client=None, error: bool = False) -> None:
        self.message.content = f"**{text}**" if error else text
        if self.notify is not None and client is not None:
            self.notify(client, "Refused" if error else "Robot", text, error)

    def open(self, robot: str, client=None, wait: bool = False, uploaded: bool = False) -> threading.Thread | None:
        """Load `robot` in a thread and open it; a second while one loads is refused. wait: join it.
        uploaded: robot is an uploaded file's path, removed again when load refuses it."""
        if not self._busy.acquire(blocking=False):
            self._say("refused: another robot is loading; wait for it", client, error=True)
            if uploaded:
                os.remove(robot)
            return None
        self._say(f"loading {robot} …")

        def work():
            try:
                try:
                    arm = robots.load(robot)
                except Exception as e:  # noqa: BLE001 - its reason, in the folder
                    name = os.path.basename(robot) if uploaded else robot
                    self._say(f"refused: {name}: {str(e).replace(robot, name)}", client, error=True)
                    if uploaded:
                        os.remove(robot)
                    return
                msg = self.open_robot(arm.name)
                if msg:
                    self._say(f"{arm.name}: {msg}", client, error=True)
                    return
                note = capsule_note(arm)
                self._say(f"opened {arm.name} ({arm.nq} joints)" + (f"  \nLinks {note}." if note else ""))
            except Exception as e:  # noqa: BLE001 - the thread never dies silently
                log.exception("opening %s", robot)
                self._say(f"refused: {robot}: {e}", client, error=True)
            finally:
                self._busy.release()

        thread = threading.Thread(target=work, daemon=True, name="lab-open-robot")
        thread.start()
        if wait:
            thread.join()
        return thread

    def _on_upload(self, event) -> None:
        from app import viser_private

        value = self.upload.value
        viser_private.forget_upload_value(self.upload)
        try:
            self.open_upload(value.name, value.content, event.client)
        finally:
            if self.guard is not None:
                self.guard.done()

    def open_upload(self, name: str, content: bytes, client=None, wait: bool = False):
        """Save an uploaded URDF under the app's upload folder (never over a file) and open it by its path."""
        from app.classroom.uploads import save_upload

        shown = os.path.basename((name or "the upload").replace("\\", "/"))[:60]
        if not shown.lower().endswith(".urdf") or not content or len(content) > MAX_URDF \
                or b"<robot" not in content[:MAX_URDF]:
            return self._say(f"refused: {shown} is not a URDF (.urdf, at most {MAX_URDF // 2**20} MiB, "
                             "with a <robot> element)", client, error=True)
        if self.upload_folder is None:
            return self._say("refused: this server keeps no uploads", client, error=True)
        try:
            path = save_upload(self.upload_folder, name, content, suffix=".urdf")
        except OSError as e:
            return self._say(f"refused: {shown} could not be saved: {e.strerror or e}", client, error=True)
        return self.open(path, client, wait=wait, uploaded=True)
