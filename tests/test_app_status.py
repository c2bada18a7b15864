"""What the lab says while it waits and when a run ends, and how it stops.

Checked: the status line says Finished, Stopped or Failed (with why) once a run has ended, for the
run and for its race partner, with no time left quoted for an ended run (never
"Running: generation 300 / 300" after it ended); a run that waits for the training kernels says so, with the step;
the worker's warm-up compiles the method the page opens with first and, for a run waiting on it,
only what that run needs; `python -m app` prints every step of a warm-up that compiles, nothing of one
that loads from the cache; its wait for Ctrl-C wakes for a signal the kernel hands to another thread.
"""

from __future__ import annotations

import os
import signal
import threading

import pytest

from conftest import make_app, wait_or_kill, wait_until

import lab
import lab.running.worker as lab_worker

# the render loop may redraw a tab in the instant between its socket closing and its session ending
pytestmark = pytest.mark.filterwarnings("ignore:Queued a .* on a closed connection")


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    lab_app = make_app(tmp_path_factory.mktemp("status"))
    yield lab_app
    lab_app.stop()


@pytest.fixture
def panel(app):
    panel, state = app.panel, app.state
    yield panel
    state.reset()
    panel.race.enabled.value = False
    panel.budget.value = 0.0
    panel.generations.value, panel.population.value = 1000.0, 50.0


def status(panel) -> str:
    return panel.status.content


def test_a_run_and_its_race_partner_say_finished_when_they_end(app, panel):
    panel.generations.value, panel.population.value = 30.0, 20.0
    panel.race.enabled.value = True
    panel.race.population.value = 20.0
    assert panel.start() is None
    state = app.state
    assert wait_until(lambda: all(r.done for r in state.runners()), timeout=120)
    # the render loop's refresh, not a forced one, brings the end to the status
    assert wait_until(lambda: status(panel).startswith("**Finished**: generation 30 / 30"), timeout=30), status(panel)
    assert wait_until(lambda: f"Partner ({state.partner.label}): **Finished**, generation 30" in status(panel),
                      timeout=30), status(panel)
    assert "unning" not in status(panel)


def test_stop_says_stopped(app, panel):
    panel.generations.value = 100_000.0
    assert panel.start() is None
    assert wait_until(lambda: app.state.progress()["generation"] >= 3, timeout=120)
    assert wait_until(lambda: status(panel).startswith("**Running**"), timeout=30)
    assert panel.stop() is None
    assert wait_until(lambda: status(panel).startswith("**Stopped**: generation"), timeout=30), status(panel)
    assert "unning" not in status(panel)


def test_a_run_that_spends_its_time_budget_says_finished_without_time_left(app, panel):
    panel.budget.value = 1.0  # s of optimizer time; the method's defaults for it, generations unbounded
    assert panel.start() is None
    assert wait_until(lambda: app.state.runner.done, timeout=120)
    assert wait_until(lambda: status(panel).startswith("**Finished**"), timeout=30), status(panel)
    assert "left" not in status(panel) and "of its 1 s" in status(panel), status(panel)


def test_a_run_whose_process_dies_says_failed_and_why(app, panel):
    panel.generations.value = 100_000.0
    assert panel.start() is None
    assert wait_until(lambda: app.state.progress()["generation"] >= 3, timeout=120)
    os.kill(app.state.runner.pid, signal.SIGKILL)
    assert wait_until(lambda: status(panel).startswith("**Failed**"), timeout=30), status(panel)
    assert "It failed: the training process exited with code -9" in status(panel), status(panel)


def test_a_run_waiting_for_the_training_kernels_says_which_step(app, panel, monkeypatch):
    waits = "step 2 of 7 (CMA-ES for serial arms), about 12 s"
    monkeypatch.setattr(lab_worker.ProcessRunner, "preparing", property(lambda self: waits))
    panel.generations.value = 100_000.0
    assert panel.start() is None
    assert wait_until(lambda: f"preparing the training kernels: {waits}" in status(panel), timeout=30), status(panel)
    assert status(panel).startswith("**Running**")
    monkeypatch.undo()  # ready: the run's own numbers
    assert wait_until(lambda: status(panel).startswith("**Running**: generation"), timeout=30), status(panel)


# ---------------------------------------------------------------------- the warm-up
def _warm_up(spare: bool, config=None) -> list:
    """The Warmup states a worker told, to its end (a spare started, or a worker with config's run)."""
    told = []

    def listen(w) -> None:
        told.append((w.pid, w.index, w.steps, w.label, w.done))

    lab_worker.on_warmup(listen)
    proc = lab_worker._spawn(spare=spare)
    try:
        if config is not None:
            runner = lab_worker.ProcessRunner(config)
            runner._claim()
            runner._proc = proc
            runner._command("run", config, runner.run_id, 1, None)
            threading.Thread(target=runner._read, daemon=True).start()
        assert wait_until(lambda: proc.warmup.done, timeout=300)
        if config is not None:
            assert runner.join(300).state == "finished"
    finally:
        lab_worker._listeners.remove(listen)
        proc.kill()
        proc.wait()
    return [t[1:] for t in told if t[0] == proc.pid]


def test_a_spare_compiles_the_method_the_page_opens_with_first_and_then_every_other():
    from lab.running import warmup

    told = _warm_up(spare=True)
    steps = [(index, label) for index, steps, label, done in told if not done]
    # the kinematics, the opened robot's kernels, the app's solvers, then every method's (each key once)
    n = len(warmup.plan(robot="planar"))
    assert [index for index, _ in steps] == list(range(1, n + 1))
    assert lab.TrainConfig.preset(robot="planar").method == "cmaes"
    assert steps[1][1] == "CMA-ES for planar"
    assert any(label.startswith("CMA-ES for trees") for _, label in steps[2:])
    assert told[-1][-1] is True  # and says when it is done


@pytest.mark.parametrize("method", ["neat", "neat_cma"])
def test_a_worker_with_its_run_waiting_compiles_only_what_that_run_needs(method):
    """neat_cma calls NEAT's kernels alone (its Method.warms_with): NEAT's step is its own."""
    config = lab.TrainConfig.preset(robot="planar", method=method, generations=2, population=10)
    told = _warm_up(spare=False, config=config)
    labels = [label for _i, _n, label, done in told if not done]
    assert labels == ["forward kinematics", "NEAT for serial arms"]


def test_python_m_app_prints_every_step_of_a_warm_up_that_compiles_and_nothing_from_the_cache(capsys):
    from app.__main__ import WarmupLines

    lines = WarmupLines()
    cached = lab_worker.Warmup(pid=1)
    for k in (1, 2, 3):
        cached.index, cached.steps, cached.label = k, 3, f"part {k}"
        lines(cached)
    cached.done = True
    lines(cached)
    assert capsys.readouterr().out == ""
    cold = lab_worker.Warmup(pid=2)
    cold.index, cold.steps, cold.label, cold.expected = 1, 3, "forward kinematics", 6.0
    lines(cold)
    cold.compiling = True  # numba missed its cache in step 1
    lines(cold)
    for k in (2, 3):
        cold.index, cold.label = k, f"part {k}"
        lines(cold)
    cold.done, cold.seconds = True, 40.0
    lines(cold)
    out = capsys.readouterr().out.splitlines()
    assert out == ["  preparing the training kernels: step 1 of 3, forward kinematics (about 6 s)",
                   "  preparing the training kernels: step 2 of 3, part 2 (about 6 s)",
                   "  preparing the training kernels: step 3 of 3, part 3 (about 6 s)",
                   "  training kernels ready (40 s, once: later starts load them)"]


def test_a_warm_up_that_loads_from_the_cache_names_no_wait_in_the_tab():
    w = lab_worker.Warmup(pid=3)
    w.index, w.steps, w.label, w.expected = 2, 7, "CMA-ES for serial arms", 12.0
    assert w.describe() is None  # nothing compiled (yet): a load takes milliseconds
    w.compiling = True
    assert w.describe().startswith("step 2 of 7 (CMA-ES for serial arms), about 1")
    w.since -= 30.0
    assert "30 s so far (about 12 s expected)" in w.describe()
    w.expected = None  # nothing measured on this machine yet: no number made up
    assert w.describe() == "step 2 of 7 (CMA-ES for serial arms), 30 s so far (the first on this machine: no estimate yet)"
    w.done = True
    assert w.describe() is None


# ---------------------------------------------------------------------- Ctrl-C
def test_the_wait_for_ctrl_c_wakes_for_a_signal_handed_to_another_thread():
    """The kernel may deliver a process's signal to any thread that does not block it; Python runs the
    handler only in the main thread, which a sleep does not wake (a Ctrl-C lost under load).
    SignalWait.wait returns when the signal is handed to another thread."""
    from app.__main__ import SignalWait

    asleep, sent, done = threading.Event(), [], threading.Event()

    def bystander() -> None:  # a thread that happens to take the signal (a sleep it resumes)
        asleep.set()
        done.wait(60)

    def sender(target: int, main: int) -> None:
        asleep.wait(60)
        while not done.is_set():
            if len(sent) < 50:
                signal.pthread_kill(target, signal.SIGUSR1)  # to the other thread only
                sent.append("other")
            else:  # the guard: wake the main thread itself, so that a lost signal fails, not hangs
                signal.pthread_kill(main, signal.SIGUSR1)
                sent.append("main")
            done.wait(0.1)

    previous = signal.getsignal(signal.SIGUSR1)
    waiting = SignalWait((signal.SIGUSR1,))  # never the default action (the end of pytest)
    other = threading.Thread(target=bystander, daemon=True)
    other.start()
    threading.Thread(target=sender, args=(other.ident, threading.main_thread().ident), daemon=True).start()
    try:
        assert waiting.wait() == signal.SIGUSR1
    finally:
        done.set()
        waiting.close()
        signal.signal(signal.SIGUSR1, previous)
    assert "main" not in sent, f"the wait woke only when the main thread itself was signalled ({len(sent)} sent)"


def test_ctrl_c_during_a_cold_warm_up_ends_the_app_and_its_compiling_worker(tmp_path, wait_ended):
    """An empty numba cache (a fresh clone): python -m app tells each step of the training kernels'
    warm-up; a Ctrl-C while they compile ends the app (rc 0, no traceback) and the worker compiling
    them, which would otherwise compile for a minute more and hold the terminal's pipe (the app is not
    to outlive a Ctrl-C by that minute on a loaded machine)."""
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    proc = subprocess.Popen([sys.executable, "-m", "app", "--port", "0", "--no-record", "--notebook",
                             str(tmp_path / "nb.db")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env)
    out, workers = [], []
    try:
        for line in proc.stdout:
            out.append(line)
            if "Ctrl-C stops" in line:
                break
        text = "".join(out)
        from lab.running.warmup import plan

        steps = len(plan(robot="planar"))
        assert f"preparing the training kernels: step 1 of {steps}, forward kinematics" in text, text
        children = Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()
        workers = [int(pid) for pid in children
                   if b"lab.running.worker" in Path(f"/proc/{pid}/cmdline").read_bytes()]
        assert workers  # the spare, compiling
    finally:
        proc.send_signal(signal.SIGINT)
        rest, _ = wait_or_kill(proc, 60)
    assert proc.returncode == 0 and "Traceback" not in rest, rest[-3000:]
    for pid in workers:
        wait_ended(pid, 30)
