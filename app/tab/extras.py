"""What a tab shows for a class, beside its goals (app/tab/goals.py): the population cloud at each
goal marker, a race partner's arm at goal 1, and the lesson link.

GoalExtras and TabExtras are mixed into GoalView and TabSession: they use their arm, scene, lock
and goals. The render loop calls TabSession.refresh, which calls refresh_population: the cloud
is redrawn at most every POPULATION_PERIOD, when the run sent a new population, a marker moved or
a toggle changed; the partner's arm when its controller changed (and in the marker callback, as
the run's own arm).
"""

from __future__ import annotations

import numpy as np

from app.startup import made_for
from app.tab.scene import ArmView
from app.training.live import candidate_colors

POPULATION_PERIOD = 0.2  # s: a tab's population cloud is redrawn at most 5 times a second
PARTNER = (160, 90, 220)  # a race's second run: its arm at the same marker


class GoalExtras:
    """A goal's population cloud and race partner's arm (self: a GoalView)."""

    def update_partner(self, controller) -> None:
        """The race partner's arm at partner(goal) (hidden without a partner)."""
        view = self.partner_view
        if controller is None:
            view.visible = False
            self.partner_error = self.partner_angle = np.nan
            return
        q = controller(self.query[None])[0]
        errors, self.partner_angle = self.errors_of(q)
        self.partner_error = float(errors.max())  # the worst effector
        with self.tab.client.atomic():
            view.set_q(q)
            if not view.visible:
                view.visible = True

    def draw_population(self, reach: np.ndarray | None, q: np.ndarray | None, colors, faint: bool) -> None:
        """The population's end-effector points (n, 3) at this goal ((n, E, 3) on a tree: every
        effector's), and with `faint` each candidate's arm as faint segments (q: (n, nq); a tree's
        each joint to its parent, arm.point_parents); reach None hides them. colors: (n, 3), one per
        candidate."""
        scene, size, base = self.tab.client.scene, self.tab.ws["size"], f"/tab/goal{self.index}"
        if reach is None:
            for h in (self.cloud, self.faint):
                if h is not None:
                    h.visible = False
            return
        points = np.ascontiguousarray(np.reshape(reach, (-1, 3)), dtype=np.float32)
        per_candidate = np.asarray(colors, dtype=np.uint8)
        colors = np.ascontiguousarray(np.repeat(per_candidate, len(points) // max(len(per_candidate), 1), axis=0))
        if self.cloud is not None and len(np.asarray(self.cloud.points)) == len(points):
            # the same node, new values: about 0.1 ms against 0.7 ms for adding it again
            self.cloud.points, self.cloud.colors = points, colors
            if not self.cloud.visible:
                self.cloud.visible = True
        else:
            self.cloud = scene.add_point_cloud(f"{base}/population", points, colors, point_size=self.tab.ws["point"],
                                               point_shape="circle", precision="float32")
        if faint:
            arm = self.tab.arm
            chain = arm.joint_positions(q)  # (n, 1 + nq + E, 3): the base, the joints, the effectors
            parents = arm.point_parents
            child = np.flatnonzero(parents >= 0)  # a serial arm: a polyline, each point to the one before
            segments = np.stack([chain[:, parents[child]], chain[:, child]], axis=2).reshape(-1, 2, 3)
            light = (0.45 * per_candidate.astype(float) + 0.55 * 255).astype(np.uint8)
            seg_colors = np.repeat(light, len(child), axis=0)[:, None, :].repeat(2, axis=1)
            segments = segments.astype(np.float32)
            if self.faint is not None and np.shape(self.faint.points) == segments.shape:
                # the same node, new values (as the cloud): a tree's faint arms are thousands of segments
                self.faint.points, self.faint.colors = segments, seg_colors
                if not self.faint.visible:
                    self.faint.visible = True
            else:
                self.faint = scene.add_line_segments(f"{base}/population_arms", segments, seg_colors,
                                                     thickness=0.003 * size)
        elif self.faint is not None:
            self.faint.visible = False


class TabExtras:
    """A tab's population toggles' effect, the race partner and the lesson link (self: a TabSession)."""

    def partner_controller(self):
        partner = self.state.partner
        if partner is None or partner.runner.config.robot != self.arm.name or self.state.replaying:
            return None
        return partner.controller

    def _population_changed(self) -> None:
        self.population_drawn = None
        self.last_population = 0.0

    def refresh_population(self, now: float) -> bool:
        """Redraw the population clouds (at most every POPULATION_PERIOD, or the tab's longer `period`)
        when the population, a goal or a toggle changed; the race partner's arm when its controller
        changed. True when it sent anything."""
        state = self.state
        partner = state.partner
        drew = False
        with self.lock:
            if self.closed or not self.goals:
                return drew
            g0 = self.goals[0]
            if partner is not None and partner.version != self.partner_version:
                if g0.partner_view is None:
                    g0.partner_view = ArmView(self.client.scene, self.arm, "/tab/goal0/partner", opacity=0.6, tint=PARTNER)
                self.partner_version = partner.version
                g0.update_partner(self.partner_controller())
                self.table_dirty = drew = True
            elif partner is None and g0.partner_view is not None and g0.partner_view.visible:
                g0.update_partner(None)
                self.partner_version, drew = None, True
            if now - self.last_population < max(POPULATION_PERIOD, self.period):
                return drew
            track = state.track
            population = track.population if track is not None and not state.replaying else state.replayed_population
            goals = np.stack([g.query for g in self.goals])
            key = (id(population), goals.tobytes(), self.show_population.value, self.faint_arms.value,
                   self.by_species.value)
            if key == self.population_drawn:
                return drew
            self.population_drawn, self.last_population = key, now
            self._draw_population(population, goals)
        return True

    def _draw_population(self, population, goals: np.ndarray) -> None:
        if population is None or not self.show_population.value or population.controllers is None \
                or not made_for(population.controllers[0], self.arm):
            recorded = population is not None and population.controllers is None and population.points is not None
            for g in self.goals:
                g.draw_population(None, None, None, False)
            if recorded and self.show_population.value:  # a replayed recording: its cloud at the display goal
                self.goals[0].draw_population(population.points, None, candidate_colors(population, self.by_species.value),
                                              False)
            return
        if getattr(self, "goal_kind", "position") == "pose":  # pose controllers: each on the poses
            q = np.stack([np.asarray(c(goals), dtype=np.float64) for c in population.controllers])
        else:
            q = population.joints(goals)  # (n, goals, nq)
        reach = self.arm.fk(q.reshape(-1, q.shape[-1])).reshape(*q.shape[:2], -1, 3)  # (n, goals, E, 3)
        colors = candidate_colors(population, self.by_species.value)
        with self.client.atomic():
            for k, g in enumerate(self.goals):
                g.draw_population(reach[:, k], q[:, k], colors, self.faint_arms.value)

    def show_lesson(self, link: str, params: dict, presenter_link: str | None = None) -> None:
        """The lesson link of the panel's settings (written only when it changes): the students' (no
        token); on a presenter's tab of a server with a token, also the presenter's own (presenter_link:
        the same settings with the token, its tab a presenter), labelled not to be shared."""
        if getattr(self, "_lesson_link", None) == (link, presenter_link) or self.closed:
            return
        self._lesson_link = (link, presenter_link)
        what = ", ".join(f"{k} {v}" for k, v in params.items() if k != "lesson")
        text = (f"**For the students:** [Open this lesson]({link}) in another browser: a tab with these settings "
                f"({what}).\n\n```\n{link}\n```")
        if presenter_link:
            text += (f"\n\n**For you (presenter) — do not share:** [this link]({presenter_link}) opens the lesson "
                     f"as a presenter (it holds the presenter token; the lesson's settings are applied to the "
                     f"class's run).\n\n```\n{presenter_link}\n```")
        self.lesson.content = text
