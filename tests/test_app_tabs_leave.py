"""Tabs that connect and close leave nothing behind (a server kept 15-18 MiB per 300 such
tabs, round after round). The property, not the RSS (benchmarks/bench_app_memory.py --plain prints
that): once the tabs have closed, no per-tab structure of the app, nor viser's, holds an entry for
them, for presenters and for a class's viewers (My experiment, their own replay), in a lesson too."""

from __future__ import annotations

import gc
import urllib.parse
import weakref

import pytest

from app.classroom.lesson import LESSONS
from app.tab.ikworker import IK_WORKER
from conftest import make_app, tab_of, wait_until

TABS = 6


def per_tab(app) -> dict:
    """Every structure of the app and of viser that holds something per tab (client id, session)."""
    server, ws = app.server, app.server._websock_server
    return {
        "app.sessions": app.sessions, "app closed-tab ids": app._gone,
        "class_runs names": app.class_runs._names, "class_runs lesson seats": app.class_runs._seats,
        "class_runs next seats": app.class_runs._next_seat,
        "access roles": app.access._roles, "access viewers": app.access._viewers,
        "uploads starts": app.runs.uploads._starts, "board's large charts": app.board._big,
        "board's phone tables": app.board._phones,
        "ik worker due": IK_WORKER._due,
        "viser clients": server._connected_clients, "viser client states": ws._client_state_from_id,
        "viser connections": ws._live_connections,
        "viser broadcast cursors": ws._broadcast_buffer.generator_cursors,
    }


def lesson_url(app) -> str:
    """A lesson link that seats each viewer in a class's search (ClassRuns.lesson_seat)."""
    link = LESSONS["class-as-a-search"].link(app.url)
    return urllib.parse.unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")


def held(app, ids) -> dict:
    out = {}
    for name, struct in per_tab(app).items():
        keys = list(struct)
        mine = [k for k in keys if k in ids or getattr(k, "client", None) is not None and k.client.client_id in ids]
        if mine:
            out[name] = mine
    return out


@pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
@pytest.mark.parametrize("viewers", [False, True])
def test_closed_tabs_leave_no_entry_in_any_per_tab_structure(tmp_path, viewers):
    app = make_app(tmp_path, presenter_token="teacher" if viewers else None)
    try:
        for round_ in range(2):
            tabs = [tab_of(lesson_url(app) if round_ and viewers else app.url) for _ in range(TABS)]
            assert wait_until(lambda: len(app.sessions) == TABS, 60)
            ids = set(app.sessions)
            sessions = [weakref.ref(s) for s in app.sessions.values()]
            if viewers:  # each a viewer with its name and, on the lesson link, its seat
                assert all(app.sessions[i].my_run is not None for i in ids)
                assert set(app.class_runs._names) >= ids
                if round_:
                    assert wait_until(lambda: sum(map(len, app.class_runs._seats.values())) == TABS, 30)
            for tab in tabs:
                tab.close()
            assert wait_until(lambda: not app.sessions and not app.server.get_clients(), 60)
            assert wait_until(lambda: not held(app, ids), 30), held(app, ids)
            assert wait_until(lambda: gc.collect() >= 0 and all(ref() is None for ref in sessions), 30)
    finally:
        app.stop()
