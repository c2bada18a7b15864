"""The runs list and replay panel (shared by all tabs).

The list holds every notebook entry (runs started in the app, kept across restarts) and any
other recording found in the recordings folder; an uploaded .rrd is saved under
recordings/uploads/ and opened. Opening a run reads its Rerun recording (lab.recording.replay); the
generation slider then shows the controller logged at or before that generation, and every
tab's arms follow their goal markers with it. An entry whose recording is gone replays its
final controller only. "Back to live" returns to the training run (or the startup controller).
A file that cannot be read is refused with a message and nothing else changes. A run of another
arm than the one shown (a planar recording uploaded into a g1 lab) switches the lab to its arm, and
says so; while a run is going, or when its controller was not made for the arm it names, it is
refused by name and nothing changes.
"""

from __future__ import annotations

import glob
import os
import time

import lab
import robots

from app import viser_private
from app import any_robot
from app.classroom.uploads import MAX_UPLOAD, UploadGuard, not_a_recording_file, save_upload
from app.panels.train import notify
from app.startup import made_for
from app.training.notebook import label


class RunsPanel:
    def __init__(self, gui, app):
        self.app, self.state = app, app.state
        self.choice = gui.add_dropdown("Run", ("(none)",), initial_value="(none)")
        self.open_button = gui.add_button("Open", icon="folder-open")
        self.upload = gui.add_upload_button("Upload a recording (.rrd)", icon="upload", mime_type="*/*")
        self.slider = gui.add_slider("Generation", min=0, max=1, step=1, initial_value=0, disabled=True)
        self.live_button = gui.add_button("Back to live", icon="player-play")
        self.download_button = gui.add_button(
            "Download this run", icon="download",
            hint="the open run's recording (.rrd: Upload opens it again, on any robot the lab can load); a run "
                 "whose recording is gone: its controller as JSON, with its robot string and URDF sha256")
        self.download_button.on_click(lambda e: self.download(e.client))
        self._entry = None  # the notebook entry of the run open (None: a file, or nothing)
        self.details = gui.add_markdown("")
        self.message = gui.add_markdown("")
        self.recording = None  # lab.recording.replay.Recording being replayed
        self._items: dict[str, tuple[str, object]] = {}  # label -> ("entry", dict) or ("file", path)
        self._listed_at, self._listing = 0.0, None
        self.open_button.on_click(lambda e: self.open(self.choice.value, e.client))
        # uploads are checked as they start and as their parts arrive, before viser buffers them
        self.uploads = UploadGuard(os.path.join(app.recordings, "uploads"), allowed=getattr(app, "upload_refusal", None),
                                   notify=self._tell)
        viser_private.guard_uploads(app.server, self.uploads.start, self.uploads.part)
        self.upload.on_upload(self._on_upload)
        self.slider.on_update(lambda e: self.scrub(int(self.slider.value), e.client))
        self.live_button.on_click(lambda e: self.live())

    # ------------------------------------------------------------------ uploads
    def _on_upload(self, event) -> None:
        value = self.upload.value
        viser_private.forget_upload_value(self.upload)  # else viser keeps the last file in memory
        try:
            self.open_upload(value.name, value.content, event.client)
        finally:
            self.uploads.done()

    def _tell(self, client_id: int, text: str) -> None:
        """An upload refused or dropped: told to its tab only (a notification)."""
        notify(self.app.server.get_clients().get(client_id), "Upload", text)

    def sweep_uploads(self) -> None:
        """Drop uploads that stalled (and what viser buffered of them)."""
        for transfer in self.uploads.sweep():
            viser_private.drop_upload(self.app.server, transfer)

    # ------------------------------------------------------------------ the list
    def refresh(self, force: bool = False) -> None:
        """Re-list notebook entries and recordings (every 2 s at most, from the render loop)."""
        self.sweep_uploads()
        now = time.monotonic()
        if not force and now - self._listed_at < 2.0:
            return
        self._listed_at = now
        entries = self.state.notebook.entries()
        skipped = self.state.notebook.skipped()
        note = f"Notebook entries skipped (not runs): {', '.join(skipped)}" if skipped else ""
        if self.state.notebook.read_only is not None:  # said here as long as it holds, in the log once
            note = (f"Notebook read-only ({self.state.notebook.read_only}): new runs are listed until the app "
                    "stops, not kept." + (f"  \n{note}" if note else ""))
        waiting, why = self.state.notebook.not_saved()
        if waiting:  # a write failed (locked by another program, a full disk): the notebook retries it
            note = (f"{waiting} run{'' if waiting == 1 else 's'} not saved yet: {why}; retrying."
                    + (f"  \n{note}" if note else ""))
        if note != getattr(self, "_skipped_note", ""):
            self._skipped_note = self.message.content = note
        known = {os.path.realpath(e["recording"]) for e in entries if e.get("recording")}
        files = sorted(glob.glob(os.path.join(self.app.recordings, "**", "*.rrd"), recursive=True))
        listing = (tuple(e["run_id"] for e in entries), tuple(files))
        if listing == self._listing:
            return
        self._listing = listing
        items = {label(e): ("entry", e) for e in reversed(entries)}
        for f in reversed(files):
            if os.path.realpath(f) not in known:
                items[f"file: {os.path.relpath(f, self.app.recordings)}"] = ("file", f)
        self._items = items
        options = tuple(items) or ("(none)",)
        current = self.choice.value if self.choice.value in options else options[0]
        self.choice.options = options
        self.choice.value = current

    # ------------------------------------------------------------------ opening
    def refuse(self, client, text: str) -> str:
        self.message.content = f"**{text}**"
        notify(client, "Refused", text)
        return text

    def open(self, choice: str, client=None) -> str | None:
        item = self._items.get(choice)
        if item is None:
            return self.refuse(client, "refused: pick a run first")
        kind, value = item
        if kind == "file":
            return self.open_file(value, client)
        entry = value
        path = entry.get("recording")
        if path and os.path.exists(path):
            return self.open_file(path, client, entry)
        if not entry.get("controller"):
            return self.refuse(client, f"refused: run {entry['run_id'][:6]} has neither a recording nor a controller")
        try:
            controller = lab.controller_from_dict(entry["controller"])
        except Exception as e:
            return self.refuse(client, f"refused: the notebook's controller does not load: {e}")
        msg = self._show(entry["robot"], controller, f"replay {entry['run_id'][:6]}, final controller", client,
                         sha256=entry.get("urdf_sha256"))
        if msg is None:
            self.recording, self._entry = None, entry
            self.slider.disabled = True
            self.details.content = _details(entry) + "  \n(recording missing: final controller only)"
        return msg

    def open_file(self, path: str, client=None, entry: dict | None = None) -> str | None:
        from lab.recording.replay import read_recording

        if (why := not_a_recording_file(path)) is not None:  # a pipe would block, a device read without end
            return self.refuse(client, f"refused: {why}")
        try:
            rec = read_recording(path)
            doc = rec.controller_doc()
            controller = lab.controller_from_dict(doc["controller"])
            robot = rec.protocol.get("robot") or rec.protocol["config"]["robot"]
        except Exception as e:  # not a recording, not a lab run, damaged beyond salvage
            name = os.path.basename(path)  # the message names the file, not where the server keeps it
            why = str(e).replace(os.path.abspath(path), name).replace(str(path), name)
            return self.refuse(client, f"refused: {name} cannot be replayed: {why}")
        gen = int(doc["generation"])
        msg = self._show(robot, controller, f"replay {os.path.basename(path)}, generation {gen + 1}", client,
                         sha256=rec.protocol.get("urdf_sha256") or (entry or {}).get("urdf_sha256"))
        if msg is not None:
            return msg
        self.recording, self._entry = rec, entry
        self.state.replayed_population = rec.population_at(gen)
        first, last = rec.controllers[0][0], max(gen, rec.controllers[-1][0])
        self.slider.min, self.slider.max = first + 1, max(last + 1, first + 2)
        self.slider.disabled = False
        self._scrubbed = gen + 1
        self.slider.value = gen + 1
        self.details.content = _details(entry) if entry else _file_details(rec)
        return None

    def open_upload(self, name: str, content: bytes, client=None) -> str | None:
        """Save an uploaded recording under recordings/uploads/ (beside, never over, a file of the
        same name) and open it."""
        from lab.recording.replay import read_recording

        shown = (name or "the upload")[:60]
        if not name.lower().endswith(".rrd") or len(content) > MAX_UPLOAD or not content.startswith(b"RRF"):
            return self.refuse(client, f"refused: {shown} is not a Rerun recording (.rrd)")
        try:
            path = save_upload(os.path.join(self.app.recordings, "uploads"), name, content, check=read_recording)
        except OSError as e:
            return self.refuse(client, f"refused: {shown} could not be saved: {e.strerror or type(e).__name__}")
        except Exception as e:  # noqa: BLE001 - not a readable recording
            return self.refuse(client, f"refused: {shown} cannot be replayed: {e}")
        self.refresh(force=True)
        msg = self.open_file(path, client)
        if msg is None and os.path.basename(path) != os.path.basename(name):
            said = self.message.content
            self.message.content = (said + "  \n" if said else "") + f"Saved as `uploads/{os.path.basename(path)}`."
        return msg

    def _show(self, robot: str, controller, source: str, client, sha256: str | None = None) -> str | None:
        """Show a replayed controller of `robot`: the lab switches to that arm first (said in the
        panel and to the tab); refused, nothing changed, while a run is going on another arm, or when
        the controller was not made for the arm the run names. sha256: the run's URDF's, when it
        recorded one: a file that changed since is said, one gone refused by name (app/any_robot.py)."""
        if not isinstance(robot, str) or not robot:
            return self.refuse(client, f"refused: unknown robot {str(robot)[:40]!r} in this run")
        changed = any_robot.replay_note(robot, sha256)
        if changed is not None and " is gone " in changed:
            return self.refuse(client, f"refused: {changed}; nothing was changed")
        try:
            arm = robots.load(robot)
        except Exception as e:  # noqa: BLE001 - an unknown name, a file gone, a frame it lacks now
            return self.refuse(client, f"refused: this run's robot {robot[:200]} cannot be loaded: {e}")
        if not made_for(controller, arm):
            return self.refuse(client, f"refused: this run names the {robot} arm, but its controller was not made "
                                       f"for it ({source}){f'; {changed}' if changed else ''}; nothing was changed")
        robot = arm.name
        before = self.state.arm.name
        if robot != before:
            msg = self.app.switch_robot(robot)
            if msg:
                why = msg.removeprefix("refused: ")
                return self.refuse(client, f"refused: this run is of the {robot} arm and the lab shows the {before} "
                                           f"arm, which it cannot leave now: {why}")
        kind = "pose" if getattr(controller, "goal", "position") == "pose" else "position"
        if kind != self.state.goal:  # a pose run's network answers pose goals: the goals follow it
            msg = self.app.panel.set_goal(kind)
            if msg:
                return self.refuse(client, f"refused: this run's network answers {kind} goals, which the lab cannot "
                                           f"switch to now: {msg.removeprefix('refused: ')}")
        msg = self.state.show_replay(controller, source)
        if msg:
            return self.refuse(client, msg)
        if robot != before:
            text = f"This run is of the {robot} arm: the lab now shows the {robot} arm (it showed the {before})."
            self.message.content = text
            notify(client, "Replay", text, error=False)
        else:
            self.message.content = ""
        if changed is not None:  # shown, and said: the file is not the one the run trained on
            self.message.content = (self.message.content + "  \n" if self.message.content else "") + f"**Note: {changed}.**"
            notify(client, "Replay", changed, error=True)
        return None

    def download(self, client) -> str | None:
        """Send the open run to the tab: its recording (.rrd, which Upload opens again), or, for a run whose
        recording is gone, {"robot", "urdf_sha256", "settings", "controller"} as JSON
        (lab.controller_from_dict(doc["controller"]) reads it back)."""
        import json

        rec, entry = self.recording, self._entry
        if rec is not None and os.path.isfile(rec.path):
            name, data = os.path.basename(rec.path), open(rec.path, "rb").read()
        elif entry is not None and entry.get("controller"):
            doc = {k: entry.get(k) for k in ("run_id", "robot", "urdf_sha256", "method", "settings", "controller")}
            name, data = f"run-{entry['run_id'][:8]}.json", json.dumps(doc).encode()
        else:
            return self.refuse(client, "refused: open a run first (Run, then Open)")
        if client is not None:
            client.send_file_download(name, data, save_immediately=True)
        return None

    # ------------------------------------------------------------------ scrubbing
    def scrub(self, generation: int, client=None) -> str | None:
        """Show the controller in force at `generation` (1-based) of the open recording."""
        rec = self.recording
        if rec is None or generation == getattr(self, "_scrubbed", None):
            return None
        self._scrubbed = generation
        try:
            doc = rec.controller_doc(generation - 1)
            controller = lab.controller_from_dict(doc["controller"])
        except Exception as e:
            return self.refuse(client, f"refused: {e}")
        msg = self.state.show_replay(controller, f"replay {rec.path.name}, generation {generation} "
                                                 f"(logged at {int(doc['generation']) + 1}, best MSE {doc['best_mse']:.4g})")
        if msg is None:  # the recorded cloud of that generation (or the last logged before it)
            self.state.replayed_population = rec.population_at(generation - 1)
        return self.refuse(client, msg) if msg else None

    def live(self) -> None:
        self.recording = None
        self.slider.disabled = True
        self.state.live()


def _details(e: dict) -> str:
    s = e.get("settings", {})
    f = lambda x: f"{x:.4g}" if isinstance(x, (int, float)) else "-"  # noqa: E731
    return (f"**{e['robot']} {e['method']}** seed {e['seed']}, population {s.get('population')}, "
            f"hidden {s.get('hidden')}, {e['generations']} generations ({e['state']}), {e['seconds']:.1f} s  \n"
            f"training MSE {f(e.get('train_mse'))}, held-out MSE {f(e.get('test_mse'))}  \n"
            f"recording `{e.get('recording') or '-'}`")


def _file_details(rec) -> str:
    p, s = rec.protocol, rec.summary or {}
    f = lambda x: f"{x:.4g}" if isinstance(x, (int, float)) else "-"  # noqa: E731
    return (f"**{p.get('robot')} {p.get('method')}** seed {p.get('seed')}, {len(rec.generations)} generations logged  \n"
            f"training MSE {f(s.get('train_mse'))}, held-out MSE {f(s.get('test_mse'))}  \n`{rec.path}`")
