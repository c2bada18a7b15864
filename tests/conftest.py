"""Helpers shared by the test modules."""

import random
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

import lab

# every registered method: tests that hold for any method are parametrized over these
METHODS = lab.methods.names()
CHROMIUM = shutil.which("chromium")  # Debian's, for the real-browser tests
NEEDS_CHROMIUM = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed (`make browser` installs it)")


def wait_or_kill(proc, timeout: float):
    """proc.communicate(timeout=...): its (stdout, stderr); a process still running after `timeout` s
    is killed before the TimeoutExpired is raised, so a slow test never leaves a server behind."""
    import subprocess

    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise


def wait_until(predicate, timeout: float = 30.0, step: float = 0.02) -> bool:
    """Poll predicate() every `step` s until it is true (True) or `timeout` s have passed (False)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return False


def process_ended(pid: int) -> bool:
    """Whether a process (our child or not) has ended; a zombie counts as ended."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True


@pytest.fixture(scope="session")
def wait_ended():
    """wait_ended(pid, timeout=60): wait until process pid has ended; fails the test if it has not."""

    def wait(pid: int, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while not process_ended(pid):
            if time.monotonic() > deadline:
                pytest.fail(f"process {pid} is still running after {timeout:g} s")
            time.sleep(0.05)

    return wait


@pytest.fixture
def keep_random_state():
    """Python's global random state (neat-python draws from it) is put back after the test."""
    state = random.getstate()
    yield
    random.setstate(state)


def make_app(folder, **kwargs):
    """A LabApp on a free port with its notebook and recordings in `folder` (no recording unless
    record=True is passed); the caller stops it."""
    from app.server import LabApp

    kwargs.setdefault("record", False)
    return LabApp(port=0, notebook=str(Path(folder) / "notebook.db"), recordings=str(Path(folder) / "rec"), **kwargs)


def tab_of(url, timeout: float = 60.0):
    """A headless tab (app.probe.Probe) of url, once the server has sent its first goal's label
    (generous: a loaded machine)."""
    from app.probe import Probe

    probe = Probe(url).start(timeout)
    probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label", timeout)
    return probe


def open_tab(app):
    """A headless tab connected to app, once its first goal's label has arrived."""
    return tab_of(app.url)


@pytest.fixture(scope="module")
def app(request, tmp_path_factory):
    """A LabApp for the test module: make_app's defaults, with the module's APP_ARGS (a dict) where it
    has them; a module that needs more defines its own `app`."""
    lab_app = make_app(tmp_path_factory.mktemp(request.module.__name__.rsplit(".", 1)[-1]),
                       **getattr(request.module, "APP_ARGS", {}))
    yield lab_app
    lab_app.stop()


@pytest.fixture
def tab(app):
    """A headless tab of the module's app, closed after the test (a module may extend it)."""
    probe = open_tab(app)
    yield probe
    probe.close()


def fmt_xyz(v) -> str:
    return " ".join(f"{x:.6f}" for x in v)


def random_joints(rng, parents) -> tuple[list, list]:
    """URDF links and joints of a random kinematic tree: joint k moves link l{k} of parent link
    parents[k], revolute, continuous or prismatic in turn, about a random (unaligned) axis at a random
    origin and rpy; the base link first."""
    links, joints = ['<link name="base"/>'], []
    for k, parent in enumerate(parents):
        kind = ("revolute", "continuous", "prismatic")[k % 3]
        axis = rng.normal(size=3)
        limit = '<limit lower="-1.5" upper="2.0" effort="1" velocity="1"/>' if kind != "continuous" else ""
        joints.append(f'<joint name="j{k}" type="{kind}"><parent link="{parent}"/><child link="l{k}"/>'
                      f'<origin xyz="{fmt_xyz(rng.uniform(-1, 1, 3))}" rpy="{fmt_xyz(rng.uniform(-3, 3, 3))}"/>'
                      f'<axis xyz="{fmt_xyz(axis / np.linalg.norm(axis))}"/>{limit}</joint>')
        links.append(f'<link name="l{k}"/>')
    return links, joints


def session_of(app, probe):
    """The app's TabSession behind a headless tab (its goal marker's owner)."""
    owner = int(probe.owner("/tab/goal0/marker"))
    assert wait_until(lambda: owner in app.sessions)
    return app.sessions[owner]


def last_pose(probe, name):
    """(position, wxyz) last sent for a scene node."""
    msgs = list(probe.messages)
    pos = next(m["position"] for _t, m in reversed(msgs) if m["type"] == "SetPositionMessage" and m["name"] == name)
    wxyz = next(m["wxyz"] for _t, m in reversed(msgs) if m["type"] == "SetOrientationMessage" and m["name"] == name)
    return np.array(pos), np.array(wxyz)
