"""Memory of a lab that switches robots: a g1 lab grew from 478 to 791 MiB while 19 lesson tabs switched
robots. Not a leak that grows per switch: each robot visited kept its visual model for good, each mesh
with its collision tree (160 MiB for the g1, 30 times the vertices the tabs are sent; 1 GB for the 16
robots). Now only the vertices are kept per robot (robots.visual.visual_geometry), the models built
for them are let go, and robots.Arm.visual_model keeps VISUAL_MODELS at most. A closed tab leaves
nothing behind. The RSS figures: benchmarks/bench_app_memory.py."""

import gc
import weakref
from urllib.parse import unquote

import pytest

import robots
import robots.arm as robot_arm
from conftest import make_app, wait_until
from robots.visual import visual_geometry

SWITCHES = ("planar", "ur5", "talos-legs", "g1", "scara", "panda")


def test_the_vertices_of_an_arm_are_kept_and_its_visual_model_is_not():
    robot_arm._visual_cache.cache_clear()
    for name in ("g1", "ur5", "panda"):
        arm = robots.load(name)
        geometry = visual_geometry.__wrapped__(arm)  # read afresh, as at an arm's first visit
        assert sum(g.kind == "Mesh" for g in geometry) > 0
        assert robot_arm._visual_cache.cache_info().currsize == 0  # the model it was read from is gone
    for name in ("g1", "ur5", "panda", "talos-legs"):
        robots.load(name).visual_model()
    assert robot_arm._visual_cache.cache_info().currsize == robot_arm.VISUAL_MODELS == 2
    arm = robots.load("talos-legs")
    assert arm.visual_model() is arm.visual_model()  # the latest is kept for its next call
    assert arm.visual_model(keep=False) is not arm.visual_model()


@pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")
def test_lesson_tabs_switching_robots_on_a_g1_lab_leave_no_model_nor_tab_behind(tmp_path):
    from app.classroom.lesson import lesson_link
    from app.probe import Probe

    app = make_app(tmp_path, robot="g1")
    robot_arm._visual_cache.cache_clear()
    sessions = []
    try:
        for _ in range(2):  # the second round visits arms seen before: nothing more is kept
            tabs = []
            for name in SWITCHES:  # a lesson link of each robot, opened in a new tab (a presenter: it switches)
                link = lesson_link(app.url, {"lesson": "1", "robot": name, "method": "cmaes"})
                tab = Probe(unquote(link.split("?websocket=", 1)[1]).replace("ws://", "http://")).start(60)
                tabs.append(tab)
                tab.wait_for(lambda m: m.get("name") == "/tab/goal0/label", 120)
                assert wait_until(lambda: app.state.arm.name == name and all(
                    s.arm is app.state.arm for s in list(app.sessions.values())), 120)
            sessions += [weakref.ref(s) for s in app.sessions.values()]
            assert len(app.sessions) == len(SWITCHES)
            for tab in tabs:
                tab.close()
            assert wait_until(lambda: not app.sessions and not app.server.get_clients(), 60)
            assert robot_arm._visual_cache.cache_info().currsize == 0  # the tabs' meshes: vertices only
        assert wait_until(lambda: gc.collect() >= 0 and all(ref() is None for ref in sessions), 60), \
            "a closed tab's session (its scene handles) is still held"
    finally:
        app.stop()
