"""A tab that watched the robot change holds what a tab opened on that robot holds.

Checked on the scene a headless tab is sent: after planar -> g1 -> planar -> ur5 (with goals added and
removed on the way), the tab's scene nodes are those of a tab opened fresh on the ur5 (their names
without the views' numbers, and their kinds); and no node of a drawn arm or of the error map's legend
was ever sent again under a name the tab still held. viser folds a removal and a creation of one
name that meet in a tab's queue into the creation alone, and its client, given a mesh again under
a frame given again, drew the mesh away from its arm (app/tab/scene.py).
"""

from __future__ import annotations

import re

import pytest
from conftest import open_tab, session_of, wait_until

pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")

# the nodes an arm view or the legend holds: a joint frame and each geometry under it, the legend's parts
DRAWN = re.compile(r"^/tab/goal\d+/(arm|ik|refined|partner)/j\d+/|^/error_map_key/")


def scene_nodes(probe) -> dict[str, str]:
    """The scene nodes the tab holds now: name -> kind (the message that created it); not the empty
    frames viser makes for a node's missing parents (virtual) once nothing is left under them."""
    nodes: dict[str, str] = {}
    virtual = set()
    for _t, m in list(probe.messages):
        kind, name = m.get("type", ""), m.get("name")
        if name is None or kind.startswith("Gui"):
            continue
        if kind == "RemoveSceneNodeMessage":
            nodes.pop(name, None)
        elif "props" in m:
            nodes[name] = kind
            (virtual.add if m.get("virtual") else virtual.discard)(name)
    real = [name for name in nodes if name not in virtual]
    return {name: kind for name, kind in nodes.items()
            if name not in virtual or any(other.startswith(name + "/") for other in real)}


def given_again(probe) -> list[str]:
    """Nodes of a drawn arm or the legend created under a name the tab still held."""
    live, again = set(), []
    for _t, m in list(probe.messages):
        kind, name = m.get("type", ""), m.get("name")
        if name is None or kind.startswith("Gui"):
            continue
        if kind == "RemoveSceneNodeMessage":
            live.discard(name)
        elif "props" in m:
            if name in live and DRAWN.search(name):
                again.append(f"{kind} {name}")
            live.add(name)
    return again


def without_numbers(nodes: dict[str, str]) -> dict[str, str]:
    """Names with each view's or legend's own number taken off (g3-17 -> g3, ur5-2 -> ur5)."""
    return {re.sub(r"-\d+(?=/|$)", "", name): kind for name, kind in nodes.items()}


def test_a_tab_after_robot_switches_holds_the_scene_of_a_tab_opened_on_that_robot(app):
    watched = open_tab(app)
    fresh = None
    try:
        session = session_of(app, watched)
        for robot in ("planar", "g1", "planar", "ur5"):
            if robot != app.state.arm.name:
                assert app.switch_robot(robot) is None
            assert wait_until(lambda: session.arm.name == robot and session.goals
                              and session.goals[0].label.text.startswith("net "), 120), robot
            if robot == "planar":  # a goal removed and added again: the same names, the same arm
                assert session.add_goal() is None and session.remove_goal() is None
                assert session.add_goal() is None and session.remove_goal() is None
        fresh = open_tab(app)
        assert wait_until(lambda: session_of(app, fresh).goals
                          and session_of(app, fresh).goals[0].label.text.startswith("net "), 120)
        # both tabs hold the ur5 as drawn for a new tab: its arm, ghosts, goals, floor, map and legend
        assert wait_until(lambda: without_numbers(scene_nodes(watched)) == without_numbers(scene_nodes(fresh)), 60), (
            sorted(set(without_numbers(scene_nodes(watched)).items())
                   ^ set(without_numbers(scene_nodes(fresh)).items())))
        nodes = scene_nodes(watched)
        assert any(name.startswith("/tab/goal0/arm/j") and kind == "MeshMessage" for name, kind in nodes.items())
        tops = [name for name in nodes if name.startswith("/error_map_key/") and name.endswith("/top")]
        assert len(tops) == 1 and tops[0].startswith("/error_map_key/ur5-"), tops  # the ur5's legend alone
        assert given_again(watched) == [] and given_again(fresh) == []
    finally:
        watched.close()
        if fresh is not None:
            fresh.close()
