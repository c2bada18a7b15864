"""Share a lesson: a link that opens the app with the current settings (robot, method, population,
hidden units, seed, and a race partner's method, population, hidden units and seed).

    params = lesson_params(panel)               # {"robot": "planar", "method": "cmaes", ...}
    link = lesson_link("http://host:8080", params)
    apply_lesson(app, client_query(client), client)   # a tab that connected with such a link

viser's client drops the page's query before it connects, so the settings travel in the query of
viser's own `?websocket=` URL (app/viser_private.websocket_link / client_query, the one place that
reaches into viser). Opened in another browser, the link's tab sets the training panel to the
lesson's settings, unless a run is going (then the tab is told and nothing changes). A lesson that
does not make a valid run (an unknown robot or method, a population below the method's minimum)
is refused by name and changes nothing.
"""

from __future__ import annotations

import lab
from lab import methods

from app.viser_private import websocket_link

FIELDS = ("robot", "method", "population", "hidden", "seed")
PARTNER = ("partner", "partner_population", "partner_hidden", "partner_seed")


def lesson_params(panel) -> dict:
    """The panel's settings as a lesson's parameters (values as text)."""
    params = {"lesson": "1", "robot": panel.robot.value, "method": panel._method_name()}
    for name in ("population", "hidden", "seed"):
        params[name] = _whole(getattr(panel, name).value)
    race = panel.race
    if race.enabled.value:
        params.update(partner=race._method_name(), partner_population=_whole(race.population.value),
                      partner_hidden=_whole(race.hidden.value), partner_seed=_whole(race.seed.value))
    return params


def lesson_link(page_url: str, params: dict) -> str:
    return websocket_link(page_url, **params)


def _whole(v) -> str:
    return str(int(v)) if isinstance(v, (int, float)) and float(v).is_integer() else str(v)


def lesson_configs(params: dict) -> tuple[lab.TrainConfig, lab.TrainConfig | None]:
    """The run (and race partner) a lesson describes; ValueError naming what is wrong."""
    def whole(name: str) -> int:
        try:
            return int(params[name])
        except ValueError:
            raise ValueError(f"lesson {name} must be a whole number, got {params[name]!r}") from None

    main = lab.TrainConfig.preset(robot=params.get("robot", "planar"), method=params.get("method", methods.DEFAULT_METHOD),
                                  **{k: whole(k) for k in ("population", "hidden", "seed") if k in params})
    if "partner" not in params:
        return main, None
    partner = lab.TrainConfig.preset(
        robot=main.robot, method=params["partner"], targets=main.targets, generations=main.generations,
        **{k: whole(f"partner_{k}") for k in ("population", "hidden", "seed") if f"partner_{k}" in params})
    return main, partner


def apply_lesson(app, params: dict, client=None) -> str | None:
    """Set the training panel to a lesson's settings; a message (and nothing changed) when refused.
    A query without lesson parameters is no lesson (None, nothing done)."""
    if params.get("lesson") != "1":
        return None
    panel = app.panel
    try:
        main, partner = lesson_configs(params)
    except ValueError as e:
        return _tell(client, f"refused: this lesson link does not make a run: {e}", error=True)
    if app.state.running:
        return _tell(client, "refused: a run is going; the lesson's settings are not applied (stop it, then reload "
                             "the link)", error=True)
    msg = app.switch_robot(main.robot)
    if msg:
        return _tell(client, msg, error=True)
    panel.method.value = methods.get(main.method).label  # fills that method's defaults
    panel.population.value, panel.hidden.value, panel.seed.value = float(main.population), float(main.hidden), \
        float(main.seed)
    race = panel.race
    race.enabled.value = partner is not None
    if partner is not None:
        race.method.value = methods.get(partner.method).label
        race.population.value, race.hidden.value, race.seed.value = float(partner.population), \
            float(partner.hidden), float(partner.seed)
    _tell(client, f"lesson: {main.robot}, {methods.get(main.method).label}, population {main.population}, "
                  f"{main.hidden} hidden, seed {main.seed}"
                  + (f"; race against {methods.get(partner.method).label}, seed {partner.seed}" if partner else ""),
          error=False)
    return None


def _tell(client, text: str, error: bool) -> str | None:
    if client is not None:
        client.add_notification("Lesson", text, auto_close_seconds=8.0, color="red" if error else "green")
    return text if error else None
