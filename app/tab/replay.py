"""A viewer's own in-app replay: its tab's arms show a run of the runs list, the other tabs do not.

The shared Runs tab replays for every tab and only a presenter may use it (app/classroom/access.py). A viewer
gets "Replay (this tab)" in its own GUI (client.gui): the same list, Open, a generation slider and
Back to live; what it opens changes only its own arms (TabSession.own). A run made on another arm
than the one the presenter shows is refused (the scene is shared). Recordings read for tabs are
kept in a small cache shared by all tabs (a class opening one file reads it once).
"""

from __future__ import annotations

import itertools
import os
import threading
from collections import OrderedDict

import lab

from app.startup import made_for
from app.training.state import Shown

_versions = itertools.count(-2, -1)  # a tab's own versions: negative, never a shared one
CACHE = 4  # recordings kept read


class _Cache:
    def __init__(self, size: int = CACHE):
        self.size, self._lock, self._items = size, threading.Lock(), OrderedDict()

    def read(self, path: str):
        from lab.recording.replay import read_recording

        key = (os.path.realpath(path), os.stat(path).st_mtime_ns)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        rec = read_recording(path)
        with self._lock:
            self._items[key] = rec
            while len(self._items) > self.size:
                self._items.popitem(last=False)
        return rec


RECORDINGS = _Cache()


class TabReplay:
    def __init__(self, client, session, runs):
        """client: the viewer's ClientHandle; session: its TabSession; runs: the shared RunsPanel (its list)."""
        self.session, self.runs = session, runs
        gui = client.gui
        self.client = client
        self.folder = gui.add_folder("Replay (this tab)", order=0.5, expand_by_default=False)
        with self.folder:
            self.choice = gui.add_dropdown("Run", ("(none)",), initial_value="(none)")
            self.open_button = gui.add_button("Open in this tab")
            self.slider = gui.add_slider("Generation", min=0, max=1, step=1, initial_value=0, disabled=True)
            self.live_button = gui.add_button("Back to the shared view")
            self.message = gui.add_markdown("")
        self.recording = None
        self._options = None
        self._scrubbed = None
        self.open_button.on_click(lambda e: self.open(self.choice.value))
        self.slider.on_update(lambda e: self.scrub(int(self.slider.value)))
        self.live_button.on_click(lambda e: self.live())
        self.sync()

    def sync(self) -> None:
        """The list of runs as the shared Runs tab has it (called by the render loop)."""
        options = tuple(self.runs._items) or ("(none)",)
        if options == self._options:
            return
        self._options = options
        current = self.choice.value if self.choice.value in options else options[0]
        self.choice.options = options
        self.choice.value = current

    def _say(self, text: str) -> str | None:
        self.message.content = text
        return text if text.startswith("refused") else None

    def open(self, choice: str) -> str | None:
        item = self.runs._items.get(choice)
        if item is None:
            return self._say("refused: pick a run first")
        kind, value = item
        path = value if kind == "file" else value.get("recording")
        arm = self.session.state.arm
        if path and os.path.exists(path):
            try:
                rec = RECORDINGS.read(path)
                doc = rec.controller_doc()
                controller = lab.controller_from_dict(doc["controller"])
            except Exception as e:  # noqa: BLE001 - not a readable recording
                return self._say(f"refused: {os.path.basename(path)} cannot be replayed: {e}")
            gen = int(doc["generation"])
            source = f"replay {os.path.basename(path)}, generation {gen + 1} (this tab)"
        elif kind == "entry" and value.get("controller"):
            rec, gen = None, None
            try:
                controller = lab.controller_from_dict(value["controller"])
            except Exception as e:  # noqa: BLE001
                return self._say(f"refused: the notebook's controller does not load: {e}")
            source = f"replay {value['run_id'][:6]}, final controller (this tab)"
        else:
            return self._say("refused: this run has neither a recording nor a controller")
        if not made_for(controller, arm):
            of = rec.protocol.get("robot") if rec is not None else value.get("robot") if kind == "entry" else None
            if isinstance(of, str) and of != arm.name:
                return self._say(f"refused: this run is of the {of[:40]} arm and the presenter shows the {arm.name} "
                                 f"arm: it replays in this tab once the presenter shows the {of[:40]} arm")
            return self._say(f"refused: this run was made for another arm; the presenter shows the {arm.name} arm")
        kind = "pose" if getattr(controller, "goal", "position") == "pose" else "position"
        if kind != self.session.state.goal:  # the goals are the presenter's (Train panel: Goal)
            return self._say(f"refused: this run's network answers {kind} goals and the presenter's goals are "
                             f"{self.session.state.goal}s: it replays in this tab once the presenter picks Goal: "
                             f"{kind.capitalize()}")
        self.recording = rec
        if rec is not None:
            first, last = rec.controllers[0][0], max(gen, rec.controllers[-1][0])
            self.slider.min, self.slider.max = first + 1, max(last + 1, first + 2)
            self._scrubbed = gen + 1
            self.slider.value = gen + 1
        self.slider.disabled = rec is None
        self._show(controller, source)
        return self._say("")

    def scrub(self, generation: int) -> str | None:
        rec = self.recording
        if rec is None or generation == self._scrubbed:
            return None
        self._scrubbed = generation
        try:
            doc = rec.controller_doc(generation - 1)
            controller = lab.controller_from_dict(doc["controller"])
        except Exception as e:  # noqa: BLE001
            return self._say(f"refused: {e}")
        self._show(controller, f"replay {rec.path.name}, generation {generation} "
                               f"(logged at {int(doc['generation']) + 1}, best MSE {doc['best_mse']:.4g}; this tab)")
        return None

    def _show(self, controller, source: str) -> None:
        self.session.own = Shown(self.session.state.arm, controller, source, next(_versions), self.session.state.goal)

    def live(self) -> None:
        self.recording = None
        self.slider.disabled = True
        self.session.own = None
        self._say("")
