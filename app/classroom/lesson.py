"""Share a lesson: a link that opens the app with the current settings (robot, method, population,
generations, hidden units, seed, and a race partner's method, population, hidden units and seed).

    params = lesson_params(panel)               # {"robot": "planar", "method": "cmaes", ...}
    link = lesson_link("http://host:8080", params)
    apply_lesson(app, client_query(client), client)   # a tab that connected with such a link

viser's client drops the page's query before it connects, so the settings travel in the query of
viser's own `?websocket=` URL (app/viser_private.websocket_link / client_query, the one place that
reaches into viser). Opened in another browser, the link's tab sets the training panel to the
lesson's settings, unless a run is going (then the tab is told and nothing changes). A lesson that
does not make a valid run (an unknown robot or method, a population below the method's minimum)
is refused by name and changes nothing.

A lesson of docs/lessons/ (docs/lessons/index.md lists them) is the same link with `lesson=<name>`
instead of `lesson=1`, and `views=` the views it turns on: the tab that opens it shows the lesson in a
column of its own at the left edge (client.gui.add_panel, with a close button; the lab's panel docks
at the right, Start in view), in any tab, presenter or viewer: its goal, what to set, what to watch
and the questions, with the answers (what the class should see, the figures, the code) in a folder
folded until the presenter opens it. A presenter's link also sets the shared settings, from the
lesson's fresh state (no earlier run shown). The text is docs/lessons/<name>.md, read from
the source tree beside this package (a checkout, or `pip install -e .`; a wheel ships no docs/, and
a lesson's name is then refused with the folder it looked in). An unknown lesson name is refused by
name and changes nothing.

    python -m app.classroom.lesson --list [--url http://host:8080]   # each shipped lesson's link
    python -m app.classroom.lesson --url http://host:8080 --presenter-token-file ~/.lab-token
        # each lesson's two links: the students' (viewers') and the presenter's, which carries the token

The presenter's link of a lesson is its students' link with the server's presenter token in front
(`token=...;lesson=...`): opened by the teacher, the tab is a presenter and the lesson's settings are
applied to the class's run; the students' link carries no token. The token comes from the file the
server was started with (`python -m app --presenter-token-file`), or from the presenter link the
server printed (`--presenter-link`, for a server that made a random token).
"""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import dataclass
from pathlib import Path

import lab
from lab import methods

from app.viser_private import websocket_link

FIELDS = ("robot", "method", "population", "generations", "hidden", "seed")
PARTNER = ("partner", "partner_population", "partner_hidden", "partner_seed")
DEFAULT_URL = "http://127.0.0.1:8080"  # where `python -m app` serves by default
# the lessons' texts: docs/lessons/ of the source tree this package is in
LESSONS_DIR = Path(__file__).resolve().parents[2] / "docs" / "lessons"
NAME = re.compile(r"[a-z0-9][a-z0-9-]{0,63}")
# views a lesson turns on (`views=ik.population`; those left out are turned off; `none`: all off):
# each tab's own toggles (app/tab/goals.py), and the error map, shared (a presenter's link sets it)
TAB_VIEWS = {"ik": "show_ik", "population": "show_population", "faint": "faint_arms", "species": "by_species"}
VIEWS = (*TAB_VIEWS, "map")


@dataclass(frozen=True)
class Lesson:
    """A shipped lesson: its text is LESSONS_DIR/<name>.md, its state these link parameters."""

    name: str
    params: dict

    def link(self, page_url: str = DEFAULT_URL, token: str | None = None) -> str:
        """The lesson's link; with the server's presenter token, the presenter's (its tab a presenter:
        app/classroom/access.py reads `token=` from the same query), else a viewer's."""
        return lesson_link(page_url, {**({"token": token} if token else {}), "lesson": self.name, **self.params})


def _load_lessons() -> dict:
    """The shipped lessons' states: LESSONS_DIR/lessons.json, one object of link parameters per
    lesson (content beside the lessons' texts, like a link: none when the folder is not there)."""
    path = LESSONS_DIR / "lessons.json"
    if not path.is_file():
        return {}
    return {name: Lesson(name, {k: str(v) for k, v in params.items()})
            for name, params in json.loads(path.read_text(encoding="utf-8")).items()}


LESSONS = _load_lessons()


def lesson_params(panel) -> dict:
    """The panel's settings as a lesson's parameters (values as text)."""
    params = {"lesson": "1", "robot": robot_to_link(panel.robot.value), "method": panel._method_name()}
    if getattr(panel.state, "goal", "position") == "pose":  # pose goals (app/tab/posegoal.py)
        params["goal"] = "pose"
    for name in ("population", "generations", "hidden", "seed"):
        params[name] = _whole(getattr(panel, name).value)
    race = panel.race
    if race.enabled.value:
        params.update(partner=race._method_name(), partner_population=_whole(race.population.value),
                      partner_hidden=_whole(race.hidden.value), partner_seed=_whole(race.seed.value))
    return params


def robot_to_link(robot: str) -> str:
    """A robot string in a link's few characters (viser keeps [A-Za-z0-9._~-]): every other byte as ~XX
    (erd:ur3#tool0 -> erd~3aur3~23tool0); registered names are as they are."""
    return "".join(c if re.fullmatch(r"[A-Za-z0-9._-]", c) else "".join(f"~{b:02x}" for b in c.encode())
                   for c in robot)


def robot_from_link(text: str) -> str:
    """robot_to_link's string back (a ~ not followed by two hex digits is kept as it is)."""
    out, i = bytearray(), 0
    while i < len(text):
        if text[i] == "~" and re.fullmatch(r"[0-9a-fA-F]{2}", text[i + 1:i + 3]):
            out.append(int(text[i + 1:i + 3], 16))
            i += 3
        else:
            out += text[i].encode()
            i += 1
    return out.decode("utf-8", "replace")


def lesson_link(page_url: str, params: dict) -> str:
    return websocket_link(page_url, **params)


def _whole(v) -> str:
    return str(int(v)) if isinstance(v, (int, float)) and float(v).is_integer() else str(v)


def is_lesson(params: dict) -> bool:
    """A query that carries a lesson (`lesson=1`: settings only; `lesson=<name>`: with its text)."""
    return bool(params.get("lesson"))


def lesson_text(name: str) -> tuple[str, str]:
    """(title, markdown body) of docs/lessons/<name>.md; ValueError naming the lesson when there is none."""
    path = LESSONS_DIR / f"{name}.md"
    if not NAME.fullmatch(name) or name == "index" or not path.is_file():
        known = ", ".join(lesson_names()) or f"none: no lessons in {LESSONS_DIR}"
        raise ValueError(f"no lesson named {name!r} (lessons: {known})")
    text = path.read_text(encoding="utf-8")
    first, _, rest = text.partition("\n")
    if first.startswith("# "):
        return first[2:].strip(), rest.lstrip("\n")
    return name, text


def lesson_names() -> list[str]:
    """The lessons whose text is in LESSONS_DIR (index.md is the list, not a lesson)."""
    if not LESSONS_DIR.is_dir():
        return []
    return sorted(p.stem for p in LESSONS_DIR.glob("*.md") if p.stem != "index" and NAME.fullmatch(p.stem))


def lesson_views(params: dict) -> dict[str, bool] | None:
    """{view: on} of a lesson's `views=` (None when it sets none); ValueError naming an unknown view."""
    if "views" not in params:
        return None
    wanted = [] if params["views"] in ("", "none") else params["views"].split(".")
    unknown = [v for v in wanted if v not in VIEWS]
    if unknown:
        raise ValueError(f"unknown view {unknown[0]!r} in views= (views: {', '.join(VIEWS)})")
    return {v: v in wanted for v in VIEWS}


def lesson_configs(params: dict) -> tuple[lab.TrainConfig, lab.TrainConfig | None]:
    """The run (and race partner) a lesson describes; ValueError naming what is wrong."""
    def whole(name: str) -> int:
        try:
            return int(params[name])
        except ValueError:
            raise ValueError(f"lesson {name} must be a whole number, got {params[name]!r}") from None

    if "robot" in params:  # any robot string, as a link carries it (robot_to_link)
        params = {**params, "robot": robot_from_link(params["robot"])}
    goal = params.get("goal", "position")
    if goal not in ("position", "pose"):
        raise ValueError(f"lesson goal must be position or pose, got {goal[:40]!r}")
    if goal == "pose":
        from app.tab.posegoal import pose_refusal

        if (why := pose_refusal(params.get("robot", "planar"))) is not None:
            raise ValueError(why)
    main = lab.TrainConfig.preset(robot=params.get("robot", "planar"), method=params.get("method", methods.DEFAULT_METHOD),
                                  **({"goal": "pose"} if goal == "pose" else {}),
                                  **{k: whole(k) for k in ("population", "generations", "hidden", "seed") if k in params})
    if "partner" not in params:
        return main, None
    partner = lab.TrainConfig.preset(
        robot=main.robot, method=params["partner"], targets=main.targets, generations=main.generations,
        **({"goal": "pose"} if goal == "pose" else {}), **{k: whole(f"partner_{k}") for k in ("population", "hidden", "seed") if f"partner_{k}" in params})
    return main, partner


def check_lesson(params: dict):
    """(main, partner, views, (title, text) or None) of a lesson's query; ValueError naming what is wrong."""
    name = params.get("lesson", "1")
    text = None if name == "1" else lesson_text(name)
    views = lesson_views(params)
    main, partner = lesson_configs(params)
    return main, partner, views, text


def open_lesson(app, session, params: dict, client, presenter: bool) -> str | None:
    """What a tab that connected with `params` gets: a presenter's link sets the shared settings
    (apply_lesson); a viewer's tab gets the lesson's run in its own *My experiment* (unfolded, its
    part on the first line: app/panels/my_run.py take_part), the shared settings staying the
    presenter's, which is what a viewer's link means (nothing on the tab reads as a failure); either
    tab gets the lesson's text and views in its own panel. A message (and nothing changed) when
    refused; None when the query holds no lesson."""
    if not is_lesson(params):
        return None
    try:
        _, _, views, text = check_lesson(params)
    except ValueError as e:
        why = f"refused: this lesson link does not make a run: {e}"
        if getattr(session, "my_run", None) is not None:  # said in the student's folder (and a toast)
            return session.my_run.refuse_part(why)
        return _tell(client, why, error=True)
    refused = apply_lesson(app, params, client) if presenter else None
    if session is not None:
        if views is not None:
            for view, attr in TAB_VIEWS.items():
                getattr(session, attr).value = views[view]
        if text is not None:
            show_lesson_text(session, params["lesson"], *text)
        if getattr(session, "my_run", None) is not None:  # a viewer's part of a class's search (class_hidden=)
            session.my_run.take_part(params)
    return refused


# a lesson's sections in the panel: the answers folded until the presenter opens them, the page's own
# link left out (the tab already shows the lesson); the others (goal, what to set, what to watch,
# the questions) open
ANSWERS = ("What the class should see", "Figures")
SKIPPED = ("Open the lesson",)
LESSON_WIDTH = 360  # px: the lesson's column at the left edge, the lab's panel at the right


def lesson_sections(text: str) -> list[tuple[str, str]]:
    """(heading, body) of each "## " section of a lesson's body, the text before the first heading
    under the heading "" (code blocks are not searched for headings)."""
    sections, heading, lines, fenced = [], "", [], False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("## "):
            sections.append((heading, "\n".join(lines).strip("\n")))
            heading, lines = line[3:].strip(), []
        else:
            lines.append(line)
    sections.append((heading, "\n".join(lines).strip("\n")))
    return [(h, b) for h, b in sections if h or b]


def panel_parts(text: str) -> tuple[str, str]:
    """(what the class sees, the answers) of a lesson's body, as the panel shows them: the goal, what
    to set, what to watch and the questions; then what the class should see, the figures and the
    code, for the folded folder. Links to the other pages of docs/ become their paths (a page of
    the lab's own address does not have them)."""
    shown, answers = [], []
    for heading, body in lesson_sections(text):
        if heading in SKIPPED:
            continue
        part = f"## {heading}\n\n{body}" if heading else body
        (answers if heading in ANSWERS else shown).append(part)
    return tuple(panel_headings(_local_links("\n\n".join(parts))) for parts in (shown, answers))


def _local_links(text: str) -> str:
    """[words](../x.md) -> words: `docs/x.md` (a relative link would point into the lab's own server)."""
    def path(m) -> str:
        target = (LESSONS_DIR / m.group(2).split("#", 1)[0]).resolve()
        try:
            target = target.relative_to(LESSONS_DIR.parents[1])
        except ValueError:
            pass
        return f"{m.group(1)}: `{target}`"

    return re.sub(r"\[([^\]]+)\]\((?![a-z]+:)([^)\s]+)\)", path, text)


def panel_headings(text: str) -> str:
    """Markdown headings two levels smaller (a page's "##" is too large for the panel), code blocks
    left as they are."""
    parts = re.split(r"(^```.*?^```)", text, flags=re.M | re.S)
    return "".join(part if part.startswith("```") else
                   re.sub(r"^(#{1,4}) ", lambda m: "#" * (len(m.group(1)) + 2) + " ", part, flags=re.M)
                   for part in parts)


def show_lesson_text(session, name: str, title: str, text: str) -> None:
    """The lesson in its own column at the left edge of the tab (client.gui.add_panel, docked left;
    on a phone, a section of the panel that opens on a tap), the lab's panel docked at the right:
    the controls stay in view, the scene between them. The column holds the lesson's goal, what to
    set, what to watch and the questions; what the class should see, the figures and the code are in
    a folder folded until the presenter opens it. session.lesson_view: the column (None once closed
    with its button)."""
    gui = session.client.gui
    shown, answers = panel_parts(text)
    old = getattr(session, "lesson_view", None)
    if old is not None:
        old.remove()
    column = gui.add_panel()
    with column.add_tab("Lesson"):
        gui.add_markdown(f"### {title}")
        close = gui.add_button("Close the lesson", hint=f"docs/lessons/{name}.md")
        gui.add_markdown(shown)
        with gui.add_folder("Answers: what the class should see, figures, code", expand_by_default=False):
            gui.add_markdown(answers)
    column.dock_left()
    column.set_width(LESSON_WIDTH)
    gui.main_panel.dock_right()

    def closed(_event) -> None:
        column.remove()
        session.lesson_view = None

    close.on_click(closed)
    session.lesson_view = column


def apply_lesson(app, params: dict, client=None) -> str | None:
    """Set the training panel (and the shared error map) to a lesson's settings; a message (and
    nothing changed) when refused. A query without lesson parameters is no lesson (None, nothing done)."""
    if not is_lesson(params):
        return None
    panel = app.panel
    try:
        main, partner, views, _text = check_lesson(params)
    except ValueError as e:
        return _tell(client, f"refused: this lesson link does not make a run: {e}", error=True)
    if app.state.running:
        return _tell(client, "refused: a run is going; the lesson's settings are not applied (stop it, then reload "
                             "the link)", error=True)
    # the lesson's fresh state: no earlier run's curves, status or network (the arm's own shown), as Start leaves it
    panel.trained()
    msg = app.switch_robot(main.robot)
    if msg:
        return _tell(client, msg, error=True)
    if hasattr(panel, "set_goal") and (msg := panel.set_goal(getattr(main, "goal", "position"))):
        return _tell(client, msg, error=True)
    if panel.budget.value:  # a lesson's settings have no time budget (its link carries none)
        panel.budget.value = 0.0
    panel.method.value = methods.get(main.method).label  # fills that method's defaults
    panel.population.value, panel.generations.value, panel.hidden.value, panel.seed.value = \
        float(main.population), float(main.generations), float(main.hidden), float(main.seed)
    race = panel.race
    race.enabled.value = partner is not None
    if partner is not None:
        race.method.value = methods.get(partner.method).label
        race.population.value, race.hidden.value, race.seed.value = float(partner.population), \
            float(partner.hidden), float(partner.seed)
    if views is not None and hasattr(app, "show_map"):
        app.show_map.value = views["map"]
    _tell(client, f"lesson: {main.robot}, {methods.get(main.method).label}, population {main.population}, "
                  f"{main.generations} generations, {main.hidden} hidden, seed {main.seed}"
                  + (f"; race against {methods.get(partner.method).label}, seed {partner.seed}" if partner else ""),
          error=False)
    return None


def _tell(client, text: str, error: bool) -> str | None:
    if client is not None:
        client.add_notification("Lesson", text, auto_close_seconds=8.0, color="red" if error else "green")
    return text if error else None


# the lab's address in a printed link: http(s), a host (a name, an IPv4 address or [an IPv6 one]), an
# optional port and path of characters a link carries as they are (a reverse proxy's /lab), no more
_HOST = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?|\[[0-9A-Fa-f:.]+\]")
_PATH = re.compile(r"(?:/(?:[A-Za-z0-9._~-]|%[0-9A-Fa-f]{2})*)*")


def page_url_problem(url) -> str | None:
    """What keeps `url` from being the lab's address in a printed link (one line naming it), or
    None: only http:// and https:// addresses with a host, no user name, query, fragment or space."""
    import urllib.parse

    if not isinstance(url, str) or not url:
        return "is empty: give the lab's address, like http://teacher-pc:8080"
    if any(c.isspace() or not c.isprintable() for c in url):
        return "holds a space or a control character"
    parts = urllib.parse.urlsplit(url)
    if not url.startswith(("http://", "https://")):  # lower case: the link's ws:// or wss:// follows from it
        return f"is not an http:// or https:// address (it begins {url.partition(':')[0][:20]!r}; "\
            "http and https in lower case)" if parts.scheme else "is not an http:// or https:// address (it has no scheme)"
    if "?" in url:
        return "has a query (?...): the lesson's link adds its own"
    if "#" in url:
        return "has a fragment (#...): the lesson's link ends with its own query"
    if "@" in parts.netloc:
        return "has a user name before its host (user@host): give the lab's address alone"
    host = parts.netloc.rsplit(":", 1)[0] if not parts.netloc.endswith("]") else parts.netloc
    if not host or not _HOST.fullmatch(host):
        return "has no host" if not host else f"has a host a link cannot carry as it is ({host[:60]!r})"
    try:
        port = parts.port
    except ValueError:
        port = -1
    if port is not None and not 1 <= port <= 65535 or parts.netloc.endswith(":"):
        return "has a port that is not a number in 1..65535"
    if not _PATH.fullmatch(parts.path):
        return "has a path with characters a link cannot carry as they are (letters, digits, . _ ~ - / and %XX only)"
    return None


def main(argv=None) -> int:
    """Print each lesson's link; an --url that is not the lab's http(s) address: one line and status 2."""
    import sys

    p = argparse.ArgumentParser(prog="python -m app.classroom.lesson",
                                description="The lessons of docs/lessons/ and the link that opens each.")
    p.add_argument("--list", action="store_true", help="print each lesson's name, title and link (the default)")
    p.add_argument("--url", default=DEFAULT_URL,
                   help=f"the lab's address (default {DEFAULT_URL}; a classroom server prints its own): "
                        "http:// or https://, a host, an optional port and path, no query")
    token_from = p.add_mutually_exclusive_group()
    token_from.add_argument("--presenter-token-file", default=None, metavar="PATH",
                            help="the file the server's presenter token is in (python -m app --presenter-token-file): "
                                 "each lesson's presenter link is printed too, beside the students' link")
    token_from.add_argument("--presenter-link", default=None, metavar="LINK",
                            help="the presenter link the server printed (a server with a random token): its token "
                                 "goes into each lesson's presenter link")
    args = p.parse_args(argv)
    problem = page_url_problem(args.url)
    if problem:
        print(f"error: --url {args.url[:80]!r} {problem}", file=sys.stderr)
        return 2
    token, problem = presenter_token_of(args.presenter_token_file, args.presenter_link)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    if token:
        print("Each lesson's two links: the students' (viewers: give it to the class) and the presenter's (it "
              "holds the presenter token: keep it to yourself, open it on the projector's machine).")
    for lesson in LESSONS.values():
        title = lesson_text(lesson.name)[0] if lesson.name in lesson_names() else "(no text found)"
        if token:
            print(f"{lesson.name}: {title}\n  students: {lesson.link(args.url)}\n"
                  f"  presenter: {lesson.link(args.url, token)}")
        else:
            print(f"{lesson.name}: {title}\n  {lesson.link(args.url)}")
    return 0


def presenter_token_of(token_file: str | None, presenter_link: str | None) -> tuple[str | None, str | None]:
    """(the presenter token or None, None) from a token file (its first line) or the presenter link a
    server printed; (None, why) when neither gives a token a server accepts."""
    from app.classroom.access import read_token_file, token_problem
    from app.viser_private import parse_query

    if token_file is not None:
        try:
            token = read_token_file(token_file)
        except ValueError as e:
            return None, f"--presenter-token-file {e}"
        source = "--presenter-token-file"
    elif presenter_link is not None:
        ws = parse_query(presenter_link).get("websocket", "")
        token = parse_query(ws).get("token", "")
        if not token:
            return None, ("--presenter-link holds no presenter token (the link the server prints as "
                          "'presenter link', with ?websocket=...token...)")
        source = "--presenter-link"
    else:
        return None, None
    if (why := token_problem(token)) is not None:
        return None, f"{source}: {why}"
    return token, None


if __name__ == "__main__":
    raise SystemExit(main())
