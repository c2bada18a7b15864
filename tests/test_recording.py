"""Rerun recordings: what the logger writes, that controllers come back exactly from the file
alone, and that stopped, killed and damaged runs still leave a file that loads or is refused
by name. The viewer is started and ended without leaving a process behind."""

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import lab
import robots
from conftest import METHODS
from lab.__main__ import main as cli
from lab.recording.logger import RerunLogger, default_path
from lab.recording.views import network
from lab.recording.replay import load_controller, read_recording
from lab.running.runner import Runner, build_problem

SHORT = dict(robot="planar", generations=40, population=10, targets=15, test_goals=10)
ROOT = Path(__file__).resolve().parents[1]


def logged_run(tmp_path, method, **changes):
    """A short run with a logger; returns (runner, logger, summary, events)."""
    config = lab.TrainConfig(method=method, **{**SHORT, **changes})
    runner = Runner(config)
    logger = RerunLogger(runner, path=tmp_path / f"{method}.rrd", pose_every=5)
    events = []
    runner.subscribe(logger)
    runner.subscribe(events.append)
    return runner, logger, runner.run(), events


@pytest.fixture(scope="module", params=METHODS)
def run(request, tmp_path_factory):
    return logged_run(tmp_path_factory.mktemp(request.param), request.param)


def entities(path) -> dict:
    """entity path -> set of component column names, over the whole file."""
    out = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, set()).update(ch.to_record_batch().schema.names)
    return out


# ---------------------------------------------------------------- contents
def test_every_generation_is_logged_with_the_protocol(run):
    runner, logger, summary, events = run
    rec = read_recording(logger.path)
    assert summary.state == "finished" and not rec.salvaged
    np.testing.assert_array_equal(rec.generations, np.arange(len(events)))
    np.testing.assert_array_equal(rec.best, [e.best for e in events])  # exact: no scalar is decimated
    np.testing.assert_array_equal(rec.median, [e.median for e in events])
    p = rec.protocol
    assert (p["robot"], p["method"], p["seed"]) == ("planar", runner.config.method, 0)
    np.testing.assert_array_equal(p["train_goals"], runner.problem.train_goals)
    np.testing.assert_array_equal(p["lower"], runner.problem.arm.lower)
    assert p["config"] == json.loads(json.dumps(runner.config.to_dict()))
    assert p["hyperparameters"] == json.loads(json.dumps(runner.backend.hyperparameters()))
    assert p["versions"]["rerun-sdk"] == rr.__version__
    assert rec.summary["state"] == "finished" and rec.summary["train_mse"] == summary.train_mse
    # one controller per change of the best, the first at generation 0
    changes = [e.index for k, e in enumerate(events) if k == 0 or e.controller is not events[k - 1].controller]
    assert [g for g, _ in rec.controllers] == changes and changes[0] == 0


def test_views_and_blueprint(run):
    runner, logger, _, events = run
    found = entities(logger.path)
    for entity in ("/world/arm", "/world/goals", "/world/reached", "/world/errors", "/log10_mse", "/search",
                   "/about", "/controller"):
        assert entity in found, entity
    assert "Arrows3D:vectors" in found["/world/errors"] and "LineStrips3D:strips" in found["/world/arm"]
    if graph_method(runner):
        assert {"GraphNodes:positions", "GraphEdges:edges"} <= found["/network"]
    assert len(RrdReader(logger.path).blueprints()) == 1
    RrdReader(logger.path).store()  # a cleanly closed file has its footer


def graph_method(runner) -> bool:
    """The run's method evolves graphs (NEAT's kind): its recording has a /network panel."""
    return lab.methods.get(runner.config.method).controller == "graph"


def logged_at(path, generation: int, timeline: str = "generation") -> set:
    """The entities the viewer has data for at `generation` (latest-at: static, or a row of the
    timeline at or before it). Rerun 0.41's dataframe queries need datafusion (the [catalog]
    extra), so this reads the chunks."""
    out = set()
    for ch in RrdReader(path).stream():
        if ch.is_static:
            out.add(ch.entity_path)
            continue
        rb = ch.to_record_batch()
        if timeline in rb.schema.names and min(rb.column(timeline).to_pylist()) <= generation:
            out.add(ch.entity_path)
    return out


def _views(reader) -> list:
    """The stored blueprint's views: {"class", "origin", "components"} (every component logged under
    the view's entity, e.g. VisibleTimeRanges:ranges)."""
    views, parts = {}, {}
    for ch in reader.stream(store=reader.blueprints()[0]):
        path = ch.entity_path.split("/")
        if len(path) < 3 or path[1] != "view":
            continue
        rb = ch.to_record_batch()
        view = views.setdefault(path[2], {"components": set()})
        view["components"].update(rb.schema.names)
        if "ViewBlueprint:class_identifier" in rb.schema.names:
            view["class"] = rb.column("ViewBlueprint:class_identifier").to_pylist()[-1][0] + "View"
            view["origin"] = rb.column("ViewBlueprint:space_origin").to_pylist()[-1][0]
    return list(views.values())


def logged_generations(path, entity: str) -> list:
    return sorted(g for ch in RrdReader(path).stream() if ch.entity_path == entity and not ch.is_static
                  for g in ch.to_record_batch().column("generation").to_pylist())


def test_the_first_generation_shows_the_arms_and_the_network(run):
    """Issue #31 (7): the replay showed only the goals, and an empty network panel, for the first
    hundreds of generations: poses and the network were logged for the last generation of each
    batch the writer read from its pipe, and the first batch holds every generation made while
    the writer started (~1 s). The first generation with a controller is posed."""
    runner, logger, _, events = run
    at0 = logged_at(logger.path, 0)
    for entity in ("/world/arm", "/world/reached", "/world/errors", "/world/goals", "/controller"):
        assert entity in at0, entity
    assert ("/network" in at0) == (graph_method(runner))
    # no method's recording has a panel it never fills: a graph method's /network, else the JSON
    views = _views(RrdReader(logger.path))
    detail = [v for v in views if v["class"] in ("GraphView", "TextDocumentView") and v["origin"] != "/about"]
    assert [v["origin"] for v in detail] == ["/network" if graph_method(runner) else "/controller"]
    # every view shows the latest data at the time cursor: none has a visible time range
    assert not any("range" in c.lower() for v in views for c in v["components"]), views
    # after the first: on improvement, at most every max(pose_every, g / 5) generations, and the last
    posed = logged_generations(logger.path, "/world/arm")
    assert posed[0] == 0 and posed[-1] <= len(events) - 1 and len(posed) > 1
    assert all(b - a >= max(logger.pose_every, b // 5) for a, b in zip(posed, posed[1:-1]))
    if graph_method(runner):  # the network of every controller the file holds
        assert logged_generations(logger.path, "/network") == [g for g, _ in read_recording(logger.path).controllers]


def test_poses_and_networks_do_not_depend_on_how_the_writer_reads_its_pipe(run, tmp_path):
    """The same generations in one batch, one per batch, or as the run's pipe happened to hand them
    over: the same generations posed and the same networks (the rule is applied to every generation)."""
    from lab.recording.logger import METHOD_VIEW
    from lab.recording.writer import Writer

    runner, logger, _, events = run
    method = lab.methods.get(runner.config.method)
    entities = ("/world/arm", "/world/errors", "/network", "/controller")

    def written(batches, name) -> dict:
        path = tmp_path / name
        writer = Writer({"path": str(path), "config": runner.config.to_dict(), "run_id": "batches",
                         "method": {k: getattr(method, k) for k in METHOD_VIEW}, "robot": runner.problem.arm.name,
                         "train_goals": runner.problem.train_goals, "goal_seed": runner.problem.goal_seed,
                         "hyperparameters": {}, "pose_every": logger.pose_every, "compact": False})
        for batch in batches:
            writer.write(batch)
        writer.end(None)
        writer.close()
        return {entity: logged_generations(path, entity) for entity in entities}

    whole = written([events], "whole.rrd")
    assert whole == written([[e] for e in events], "single.rrd")
    assert whole == written([events[:7], events[7:8], events[8:]], "three.rrd")
    assert whole == {entity: logged_generations(logger.path, entity) for entity in entities}


def test_mse_series_and_search_extras(run):
    runner, logger, _, events = run
    rows, times = {}, {}
    for ch in RrdReader(logger.path).stream():
        if ch.entity_path in ("/mse", "/log10_mse", "/search") and not ch.is_static:
            rb = ch.to_record_batch()
            wall = rb.column("wall_time").cast(pa.int64()).to_pylist()  # ns since the epoch
            run_time = rb.column("run_time").cast(pa.int64()).to_pylist()  # ns
            for g, v, w, t in zip(rb.column("generation").to_pylist(), rb.column("Scalars:scalars").to_pylist(),
                                  wall, run_time):
                rows[ch.entity_path, g] = v
                times[ch.entity_path, g] = (w, t)
    for e in events:  # three timelines on every row: generation, run time and the wall clock
        for entity in ("/mse", "/log10_mse", "/search"):
            wall, run_time = times[entity, e.index]  # in ns, as Rerun stores them (to the float's precision)
            assert abs(wall - e.wall_time * 1e9) < 1e3 and abs(run_time - e.seconds * 1e9) <= 1
        mse = rows["/mse", e.index]
        expected = [e.best, e.median] + ([e.worst] if np.isfinite(e.worst) else [])
        assert mse == expected  # worst only when finite
        np.testing.assert_allclose(rows["/log10_mse", e.index], np.log10(expected), rtol=1e-12)
        keys = sorted(k for k, v in e.extras.items() if isinstance(v, (int, float)))
        assert rows["/search", e.index] == [float(e.extras[k]) for k in keys]
    wanted = {"cmaes": {"sigma", "restarts"}, "neat": {"species", "nodes", "connections"},
              "neat_cma": {"species", "nodes", "connections", "tuned"},
              "gradient": {"gradient_norm", "learning_rate"}}[runner.config.method]
    assert wanted <= set(events[0].extras)


@pytest.mark.parametrize("at", ["last", "middle", "first"])
def test_load_controller_reproduces_the_logged_mse(run, at):
    runner, logger, _, events = run
    rec = read_recording(logger.path)
    generation = {"last": None, "middle": len(events) // 2, "first": 0}[at]
    controller = load_controller(logger.path, generation)
    g = len(events) - 1 if generation is None else generation
    problem = lab.problem.Problem(runner.problem.arm, runner.problem.encoding, targets=SHORT["targets"],
                                  test_goals=1, goal_seed=rec.protocol["goal_seed"])
    assert problem.controller_mse(controller) == pytest.approx(rec.best_at(g), rel=0, abs=1e-9)
    assert controller.to_dict() == events[g].controller.to_dict()  # bit for bit


def test_network_is_laid_out_in_layers(run):
    runner, _, summary, _ = run
    if runner.config.method != "neat":
        pytest.skip("CMA-ES controllers have no genome")
    c = summary.controller
    nodes, edges = network(c)
    ids = [str(x) for x in nodes.node_ids.as_arrow_array().to_pylist()]
    x = dict(zip(ids, (p[0] for p in nodes.positions.as_arrow_array().to_pylist())))
    assert {x[str(k)] for k in c.input_keys} == {0.0}
    assert {x[str(k)] for k in c.output_keys} == {max(x.values())}
    for edge in edges.edges.as_arrow_array().to_pylist():
        assert x[edge["first"]] < x[edge["second"]]  # drawn left to right
    enabled = sum(1 for *_, on in c.genome["connections"] if on)
    assert len(edges.edges.as_arrow_array()) == enabled


def test_logger_uses_its_own_stream(run):
    assert rr.get_global_data_recording() is None and rr.get_thread_local_data_recording() is None


# ---------------------------------------------------------------- paths
def test_default_path_and_a_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = lab.TrainConfig(method="cmaes", seed=3, **SHORT)
    p = default_path(config)
    assert re.fullmatch(r"recordings/planar-cmaes-s3-\d{8}-\d{6}\.rrd", p.as_posix())
    logger = RerunLogger(config, build_problem(config), path=f"{tmp_path}/runs/")  # a folder: default name inside
    logger.close()
    assert logger.path.parent == tmp_path / "runs" and logger.path.name.startswith("planar-cmaes-s3-")
    assert read_recording(logger.path).last_generation is None  # no generation, still a valid file


def test_a_default_name_is_claimed_once_in_threads_and_processes(tmp_path):
    """Loggers that pick a name in the same second (two apps on one folder) each get a file of their
    own: the name is created (O_EXCL) as it is chosen, the next one gets -2, -3 ..."""
    import threading
    from datetime import datetime

    config = lab.TrainConfig(method="cmaes", seed=0, **SHORT)
    now = datetime(2026, 12, 4, 11, 5, 0)
    got, start = [], threading.Barrier(6)

    def pick():
        start.wait()
        got.append(default_path(config, folder=tmp_path / "rec", now=now))

    threads = [threading.Thread(target=pick) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(set(got)) == 6 and all(p.is_file() for p in got)
    code = ("import sys; from datetime import datetime; import lab; from lab.recording.logger import default_path\n"
            "print(default_path(lab.TrainConfig(method='cmaes', seed=0), folder=sys.argv[1], "
            "now=datetime(2026, 12, 4, 11, 6, 0)))")
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "rec")], stdout=subprocess.PIPE, text=True,
                              cwd=ROOT) for _ in range(2)]
    paths = [p.communicate(timeout=120)[0].strip() for p in procs]
    assert [p.returncode for p in procs] == [0, 0]
    assert len(set(paths)) == 2 and all(Path(p).is_file() for p in paths)
    assert sorted(Path(p).name for p in paths) == ["planar-cmaes-s0-20261204-110600-2.rrd", "planar-cmaes-s0-20261204-110600.rrd"]


def test_two_runs_of_one_method_and_seed_in_one_second_record_two_whole_files(tmp_path, monkeypatch):
    """As a race of one method and seed (or two apps on one folder) does: two loggers, one folder, one
    second. Each run is whole in its own file, under its own run id."""
    import threading
    from datetime import datetime

    import lab.recording.logger as logger_module

    class Frozen(datetime):
        @classmethod
        def now(cls, tz=None):
            return cls(2026, 12, 4, 11, 5, 0)

    monkeypatch.setattr(logger_module, "datetime", Frozen)
    config = lab.TrainConfig(method="cmaes", seed=0, **SHORT)
    runners = [Runner(config) for _ in range(2)]
    loggers = [RerunLogger(r, path=f"{tmp_path}/rec/") for r in runners]
    assert loggers[0].path != loggers[1].path
    for r, g in zip(runners, loggers):
        r.subscribe(g)
    threads = [threading.Thread(target=r.run) for r in runners]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for g in loggers:
        g.close(wait=True)
    recs = [read_recording(g.path) for g in loggers]
    assert [(r.salvaged, r.last_generation) for r in recs] == [(False, SHORT["generations"] - 1)] * 2
    assert {r.protocol["run_id"] for r in recs} == {r.run_id for r in runners}


def test_a_logger_that_cannot_start_gives_its_claimed_name_back(tmp_path, monkeypatch):
    import lab.recording.logger as logger_module

    config = lab.TrainConfig(method="cmaes", **SHORT)

    def no_process(*_a, **_k):
        raise OSError("no process")

    with monkeypatch.context() as m:
        m.setattr(logger_module.pipes, "start", no_process)
        for path in (tmp_path / "run.rrd", f"{tmp_path}/rec/"):
            with pytest.raises(OSError, match="no process"):
                RerunLogger(Runner(config), path=path)
    assert not (tmp_path / "run.rrd").exists() and list((tmp_path / "rec").iterdir()) == []
    first = RerunLogger(Runner(config), path=tmp_path / "run.rrd")  # an explicit path, claimed too:
    with pytest.raises(FileExistsError, match="already exists"):  # a second logger is refused
        RerunLogger(Runner(config), path=tmp_path / "run.rrd")
    first.close()


def test_unwritable_path_is_refused_before_training(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    runner = Runner(lab.TrainConfig(method="cmaes", **SHORT))
    with pytest.raises(OSError, match=re.escape(str(blocker / "run.rrd"))):
        RerunLogger(runner, path=blocker / "run.rrd")
    with pytest.raises(ValueError, match="not a file"):
        RerunLogger(runner, path="/dev/null")
    assert runner.state == "idle" and not (blocker.parent / "run.rrd").exists()


def test_a_file_already_at_the_path_is_left_as_it_is_unless_overwrite(tmp_path):
    existing = tmp_path / "precious.rrd"
    existing.write_bytes(b"RRF2 yesterday's run")
    with pytest.raises(FileExistsError, match=f"recording {re.escape(str(existing))} already exists"):
        RerunLogger(Runner(lab.TrainConfig(method="cmaes", **SHORT)), path=existing)
    assert existing.read_bytes() == b"RRF2 yesterday's run"
    runner = Runner(lab.TrainConfig(method="cmaes", **SHORT))
    logger = RerunLogger(runner, path=existing, overwrite=True)
    runner.subscribe(logger)
    runner.run()
    logger.close()
    assert read_recording(existing).last_generation == SHORT["generations"] - 1


# ---------------------------------------------------------------- the command line
def test_train_cli_writes_and_prints_the_recording(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    args = ["train", "--generations", "6", "--population", "8", "--targets", "10", "--test-goals", "10", "--quiet"]
    assert cli(args + ["--recording", "out/run.rrd"]) == 0
    assert "recording     out/run.rrd" in capsys.readouterr().out
    assert read_recording(tmp_path / "out/run.rrd").last_generation == 5
    assert cli(args) == 0  # on by default
    [default] = (tmp_path / "recordings").glob("planar-cmaes-s0-*.rrd")
    assert str(Path("recordings") / default.name) in capsys.readouterr().out
    assert cli(args + ["--no-recording"]) == 0
    assert "recording" not in capsys.readouterr().out
    assert len(list((tmp_path / "recordings").iterdir())) == 1
    assert cli(args + ["--recording", str(tmp_path / "out/run.rrd" / "x.rrd")]) == 2
    assert "run.rrd" in capsys.readouterr().err


# ---------------------------------------------------------------- stops, crashes, damage
def test_a_stopped_run_closes_its_recording(tmp_path):
    config = lab.TrainConfig(method="neat", **{**SHORT, "generations": 100000})
    runner = Runner(config)
    logger = RerunLogger(runner, path=tmp_path / "stopped.rrd")
    runner.subscribe(logger)
    runner.start()
    while runner.snapshot().generation < 10:
        time.sleep(0.01)
    runner.stop()
    summary = runner.join(30)
    assert summary.state == "stopped"
    RrdReader(logger.path).store()  # footer written: closed cleanly
    rec = read_recording(logger.path)
    assert rec.summary["state"] == "stopped" and rec.last_generation == summary.generations - 1
    c = load_controller(logger.path)
    assert runner.problem.controller_mse(c) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)


def test_a_writer_that_dies_does_not_take_the_run_down(tmp_path, caplog):
    config = lab.TrainConfig(method="cmaes", **{**SHORT, "generations": 100000})
    runner = Runner(config)
    logger = RerunLogger(runner, path=tmp_path / "orphan.rrd")
    runner.subscribe(logger)
    runner.start()
    try:
        assert _wait(lambda: (read_recording(logger.path).last_generation or 0) >= 10)
        os.kill(logger.pid, signal.SIGKILL)
        logger.wait(10)  # gone: the pipe has no reader any more
        g = runner.snapshot().generation
        assert _wait(lambda: runner.snapshot().generation > g + 100)  # the run goes on without it
    finally:
        runner.stop()
    assert runner.join(30).state == "stopped"
    said = [r.getMessage() for r in caplog.records if "stopped:" in r.getMessage()]
    assert len(said) == 1 and f"recording {logger.path} stopped: its writer process exited" in said[0]
    assert "can be read back" in said[0] and "Traceback" not in caplog.text
    with pytest.raises(RuntimeError, match=f"recording {logger.path} stopped"):
        logger.close()
    assert read_recording(logger.path).last_generation >= 10  # what it had written still loads


def _wait(predicate, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if predicate():
                return True
        except (OSError, ValueError):  # the file is not there yet
            pass
        time.sleep(0.05)
    return False


def _train_until(path, generations: int, timeout: float = 60.0) -> tuple[subprocess.Popen, int]:
    """Start `python -m lab train` (endless) recording to `path`; return once it has logged `generations`,
    with the file's size when it first held a complete generation (the file only grows while it is written,
    so every prefix at least that long holds one)."""
    cmd = [sys.executable, "-m", "lab", "train", "--generations", "100000", "--population", "10", "--targets", "15",
           "--test-goals", "10", "--quiet", "--recording", str(path)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, first_size = time.monotonic() + timeout, None
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        try:
            size = path.stat().st_size
            logged = len(read_recording(path).generations)
        except (OSError, ValueError):
            continue  # not there yet
        if logged and first_size is None:
            first_size = size
        if logged >= generations:
            return proc, first_size
    proc.kill()
    pytest.fail(f"the training process logged too little: {proc.communicate()[1][-2000:]}")


def test_ctrl_c_stops_the_cli_run_and_closes_its_recording(tmp_path):
    path = tmp_path / "interrupted.rrd"
    proc, _ = _train_until(path, 20)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    rec = read_recording(path)
    assert rec.summary["state"] == "stopped" and rec.summary["generations"] == len(rec.generations) >= 20
    assert f"recording     {path}" in out
    RrdReader(path).store()  # closed with its footer


def _writer_of(pid: int) -> int:
    """The recording's writer process started by process `pid`."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if int(fields[1]) == pid and b"lab.recording.writer" in cmdline:
            return int(stat.parent.name)
    pytest.fail(f"process {pid} has no writer process")


@pytest.fixture(scope="module")
def killed(tmp_path_factory, wait_ended):
    """A `python -m lab train` process killed with SIGKILL while it writes its recording; returns once
    its writer process, which outlives it, has closed the file."""
    path = tmp_path_factory.mktemp("killed") / "killed.rrd"
    proc, first_size = _train_until(path, 30)
    deadline = time.monotonic() + 60
    while path.stat().st_size < 1.5 * first_size and time.monotonic() < deadline:  # room to cut past first_size
        time.sleep(0.05)
    writer = _writer_of(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    wait_ended(writer)
    return path, first_size


KILLED_SCRIPT = """
import sys
import lab
from lab.recording.logger import RerunLogger

runner = lab.Runner(lab.TrainConfig(method=sys.argv[2], generations=100000, population=10, targets=15, test_goals=10))
logger = RerunLogger(runner, path=sys.argv[1])
print(logger.pid, flush=True)
runner.subscribe(logger)
runner.subscribe(lambda event: print(event.index, flush=True))  # after the logger has the generation
runner.run()
"""


@pytest.mark.parametrize("method", METHODS)
def test_a_killed_run_loses_at_most_the_generation_in_flight(tmp_path, method, wait_ended):
    """SIGKILL right after the training process has printed generation n (which it does once the
    logger has returned from that generation): the file holds every generation up to n, and
    the writer, which outlives the killed process, closes it with its footer."""
    path = tmp_path / "killed.rrd"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_SCRIPT, str(path), method], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    writer = int(proc.stdout.readline())
    for line in proc.stdout:
        if int(line) >= 200:
            break
    os.kill(proc.pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL, err
    printed = int(out.split()[-1]) if out.split() else int(line)
    wait_ended(writer)
    RrdReader(path).store()  # closed with its footer, by the writer
    rec = read_recording(path)
    assert rec.summary is None and rec.last_generation >= printed
    np.testing.assert_array_equal(rec.generations, np.arange(rec.last_generation + 1))
    config = lab.TrainConfig.from_dict(rec.protocol["config"], strict=False)
    assert build_problem(config).controller_mse(load_controller(path)) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)


def test_a_killed_run_leaves_a_file_that_loads(killed):
    killed, _ = killed
    rec = read_recording(killed)
    assert rec.last_generation >= 29 and rec.summary is None  # no end was written
    np.testing.assert_array_equal(rec.generations, np.arange(rec.last_generation + 1))
    config = lab.TrainConfig.from_dict(rec.protocol["config"], strict=False)
    controller = load_controller(killed)
    assert build_problem(config).controller_mse(controller) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.999])
def test_a_file_cut_mid_frame_is_salvaged(killed, tmp_path, keep):
    killed, first_size = killed
    data = killed.read_bytes()
    cut = tmp_path / "cut.rrd"
    # cut anywhere past the point where the file first held a generation (before it: static data only,
    # whose share of the file depends on how fast the machine ran the killed process)
    cut.write_bytes(data[: first_size + int((len(data) - first_size) * keep)])
    rec = read_recording(cut)  # salvaged: the protocol and the first generations come first in the file
    assert rec.salvaged and rec.last_generation is not None and rec.last_generation <= read_recording(killed).last_generation
    config = lab.TrainConfig.from_dict(rec.protocol["config"], strict=False)
    assert build_problem(config).controller_mse(load_controller(cut)) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)


@pytest.mark.parametrize("content", [b"", b"RRF", b"hello, not a recording\n" * 10, "killed-head"])
def test_bad_files_are_refused_by_name(killed, tmp_path, content):
    killed, _ = killed
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(killed.read_bytes()[:40] if content == "killed-head" else content)
    with pytest.raises(ValueError, match=re.escape(str(bad))):
        load_controller(bad)


def test_missing_files_and_folders_are_refused_by_name(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"^no such recording: .*nope\.rrd$"):
        load_controller(tmp_path / "nope.rrd")
    with pytest.raises(ValueError, match=re.escape(str(tmp_path))):
        read_recording(tmp_path)


def test_generation_before_the_first_controller_is_refused(run):
    _, logger, _, _ = run
    with pytest.raises(ValueError, match="generation -1"):
        load_controller(logger.path, generation=-1)


# ---------------------------------------------------------------- the viewer
def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"
    except FileNotFoundError:
        return False


def test_replay_serves_the_web_viewer_and_leaves_nothing_behind(run):
    _, logger, _, _ = run
    cmd = [sys.executable, "-m", "lab", "replay", str(logger.path), "--web", "--timeout", "20"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        head = proc.stdout.readline()
        pid = int(re.search(r"viewer process (\d+)", head).group(1))
        url = re.search(r"(http://127\.0\.0\.1:\d+/\S*)", proc.stdout.readline()).group(1)
        for _ in range(100):  # the server needs a moment
            try:
                assert urllib.request.urlopen(url, timeout=2).status == 200
                break
            except OSError:
                time.sleep(0.1)
        else:
            pytest.fail(f"no web viewer at {url}")
        assert _alive(pid)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(20) in (0, 130)
    finally:
        proc.kill()
    deadline = time.monotonic() + 10
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(pid), "the viewer outlived `python -m lab replay`"


def test_replay_timeout_and_bad_paths(run, tmp_path, capsys):
    _, logger, _, _ = run
    assert cli(["replay", str(tmp_path / "missing.rrd")]) == 2
    assert "missing.rrd" in capsys.readouterr().err
    t0 = time.monotonic()
    assert cli(["replay", str(logger.path), "--web", "--timeout", "1"]) == 0
    out = capsys.readouterr().out
    pid = int(re.search(r"viewer process (\d+)", out).group(1))
    assert time.monotonic() - t0 < 15 and not _alive(pid)


EXAMPLES = sorted((ROOT / "recordings" / "examples").glob("*.rrd"))


def test_the_shipped_examples_cover_both_arms_and_methods_within_20_mb():
    names = {p.stem for p in EXAMPLES}
    assert {f"{r}-{m}-s0" for r in ("planar", "scara") for m in ("cmaes", "neat")} <= names
    assert sum(p.stat().st_size for p in EXAMPLES) <= 20 * 2**20


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_a_shipped_example_is_a_complete_run_at_the_papers_budget_whose_controller_rebuilds(path):
    rec = read_recording(path)
    config = lab.TrainConfig.from_dict(rec.protocol["config"], strict=False)
    assert (config.generations, config.population, config.targets) == (1000, 50, 70) and not rec.salvaged
    assert rec.summary["state"] == "finished" and rec.last_generation == 999
    np.testing.assert_array_equal(rec.generations, np.arange(1000))
    problem = build_problem(config)
    controller = load_controller(path)
    assert problem.controller_mse(controller) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)
    assert problem.controller_mse(controller, problem.test_goals) == pytest.approx(rec.summary["test_mse"], rel=0, abs=1e-9)


def test_a_real_arms_recording_shows_its_meshes_posed_as_the_logged_controller(tmp_path):
    """The arm's meshes are logged once (static Mesh3D under /world/robot), and each pose moves
    its joints to Pinocchio's placements at the logged controller's answer for the first goal."""
    from rerun.chunk import RrdReader

    from robots.visual import joint_poses, visual_geometry

    runner, logger, summary, _events = logged_run(tmp_path, "cmaes", robot="ur5", generations=12, targets=10)
    logger.close(wait=True)
    meshes, last = 0, {}
    for ch in RrdReader(logger.path).stream():
        if not ch.entity_path.startswith("/world/robot/"):
            continue
        rb = ch.to_record_batch()
        if "Mesh3D:triangle_indices" in rb.schema.names:
            meshes += 1
        if ch.entity_path.count("/") == 3 and "Transform3D:translation" in rb.schema.names:  # a joint's pose
            last[int(ch.entity_path.rsplit("/j", 1)[1])] = rb.column("Transform3D:translation").to_pylist()[-1][0]
    arm = robots.load("ur5")
    assert meshes == len(visual_geometry(arm)) > 0
    controller = load_controller(logger.path)
    q = controller(runner.problem.train_goals[:1])[0]
    for j, (p, _wxyz) in joint_poses(arm, q).items():
        assert np.allclose(last[j], p, atol=1e-6), j


def test_only_a_recording_is_overwritten_and_an_empty_path_is_refused(tmp_path):
    precious = tmp_path / "precious.txt"
    precious.write_text("my notes")
    config = lab.TrainConfig(**SHORT)
    with pytest.raises(FileExistsError, match="not a Rerun recording and was left as it is"):
        RerunLogger(config, path=precious, overwrite=True)
    assert precious.read_text() == "my notes"
    with pytest.raises(ValueError, match="recording path is empty"):
        RerunLogger(config, path="", overwrite=True)
    assert cli(["train", "--generations", "2", "--recording", str(precious), "--overwrite", "--quiet"]) == 2
    assert precious.read_text() == "my notes"


@pytest.mark.parametrize("generation", ["3", 2.5, True])
def test_a_generation_that_is_not_a_whole_number_is_refused_by_value(generation):
    from lab.recording.replay import RecordingError  # noqa: F401

    path = ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd"
    rec = read_recording(path)
    with pytest.raises(ValueError, match="generation must be a whole number"):
        rec.best_at(generation)
    with pytest.raises(ValueError, match="generation must be a whole number"):
        load_controller(path, generation=generation)


@pytest.mark.parametrize("argv,why", [(["--timeout", "nan"], "--timeout must be a positive"),
                                      (["--timeout", "-1"], "--timeout must be a positive"),
                                      (["--web-port", "99999"], "--web-port must be in 1..65535"),
                                      (["--web-port", "-5"], "--web-port must be in 1..65535")])
def test_replay_refuses_bad_numbers_before_starting_a_viewer(argv, why, capsys):
    path = ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd"
    assert cli(["replay", str(path), "--web", *argv]) == 2
    assert why in capsys.readouterr().err


def test_the_web_viewer_loads_the_recording_from_a_file_server_of_ours(tmp_path):
    """replay --web serves the .rrd over HTTP (with CORS for the viewer's page) instead of Rerun's
    gRPC proxy, which kept a core busy with no browser attached; other paths are 404."""
    from lab.recording.replay import serve_file

    path = ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd"
    server, url = serve_file(path, 0)
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            assert r.read() == path.read_bytes() and r.headers["Access-Control-Allow-Origin"] == "*"
        with pytest.raises(urllib.error.HTTPError):
            urllib.request.urlopen(url.rsplit("/", 1)[0] + "/etc-passwd", timeout=5)
    finally:
        server.shutdown()


def test_a_full_disk_keeps_the_results_and_says_so_in_one_line(tmp_path):
    """A recording on a full filesystem: the run's results are printed, the recording's failure is
    one line naming the file, the cause and what can be read back; no traceback (needs root to mount
    a small tmpfs; skipped elsewhere)."""
    tiny = tmp_path / "tiny"
    tiny.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(tiny)], capture_output=True).returncode:
        pytest.skip("cannot mount a small tmpfs here (needs root)")
    try:
        done = subprocess.run([sys.executable, "-m", "lab", "train", "--robot", "ur5", "--generations", "200",
                               "--test-goals", "100", "--quiet", "--recording", str(tiny / "run.rrd")],
                              cwd=ROOT, capture_output=True, text=True, timeout=240)
    finally:
        subprocess.run(["umount", str(tiny)], capture_output=True)
    out = done.stdout + done.stderr
    assert done.returncode == 0, out[-3000:]
    assert "training MSE" in done.stdout and "held-out MSE" in done.stdout
    lines = [line for line in out.splitlines() if "stopped:" in line]
    assert len(lines) == 1 and str(tiny / "run.rrd") in lines[0] and ("disk is full" in lines[0] or "disk is nearly full" in lines[0]), out[-3000:]
    assert "Traceback" not in out and "ERROR" not in out, out[-3000:]


# ---------------------------------------------------------------- a recording being written
def test_a_recording_being_written_is_read_and_replayed_as_far_as_it_is(tmp_path, capsys):
    """`lab replay` of a live logger's file said "is not a Rerun recording" while its writer was
    starting. A recording being written reads as far as it is written (live), replays that, and
    reads whole, no longer live, once closed."""
    import threading

    from lab.recording import busy

    path = tmp_path / "live.rrd"
    runner = Runner(lab.TrainConfig(**{**SHORT, "generations": 60}))
    logger = RerunLogger(runner, path=path)
    assert busy.being_written(path)  # from the moment the file is claimed, still empty
    gate, reached = threading.Event(), threading.Event()

    def hold_at_20(event):
        if event.index == 20:
            reached.set()
            gate.wait(300)

    runner.subscribe(logger)
    runner.subscribe(hold_at_20)
    runner.start()
    try:
        assert reached.wait(300)
        assert _wait(lambda: read_recording(path).last_generation == 20, timeout=120)
        rec = read_recording(path)
        assert rec.live and rec.summary is None and rec.controllers
        config = lab.TrainConfig.from_dict(rec.protocol["config"], strict=False)
        assert build_problem(config).controller_mse(load_controller(path)) == pytest.approx(rec.best[-1], rel=0, abs=1e-9)
        assert cli(["replay", str(path), "--web", "--timeout", "1"]) == 0
        out = capsys.readouterr().out
        assert "(21 generations, those written so far: its run is still being recorded)" in out
        assert not _alive(int(re.search(r"viewer process (\d+)", out).group(1)))
    finally:
        gate.set()
        runner.join()
    logger.close(wait=True)
    rec = read_recording(path)
    assert not busy.being_written(path) and not rec.live and rec.last_generation == 59 and rec.summary


@pytest.fixture
def being_started(tmp_path):
    """A claimed file whose writer is starting: empty, its lock held as a logger holds it."""
    from lab.recording import busy

    path = tmp_path / "starting.rrd"
    path.write_bytes(b"")
    fd = busy.hold(path)
    assert fd is not None and busy.being_written(path)
    yield path
    os.close(fd)


@pytest.mark.parametrize("head", [0, 3, 40])
def test_a_recording_whose_writer_is_starting_is_said_to_be_written_not_damaged(being_started, head, capsys, monkeypatch):
    """Empty, or cut before its run's first frames (as a file is in its writer's first second):
    said to be written, by name; once nobody writes it, the same bytes are damaged, said so."""
    from lab.recording import replay
    from lab.recording.replay import RecordingInProgress

    if head:
        being_started.write_bytes((ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd").read_bytes()[:head])
    with pytest.raises(RecordingInProgress, match=re.escape(str(being_started)) + " is being written: its run has "
                       "started and has not logged its first generation yet .*try again in a few seconds"):
        read_recording(being_started)
    monkeypatch.setattr(replay, "START_WAIT", 0.5)
    assert cli(["replay", str(being_started), "--web", "--timeout", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is being written" in err[0] and "not a Rerun recording" not in err[0], err


@pytest.mark.parametrize("head,why", [(0, "is empty: a recording whose run never wrote to it"),
                                      (40, "cannot be read|not one of a lab training run")])
def test_the_same_bytes_nobody_writes_are_damaged(tmp_path, head, why):
    from lab.recording.replay import RecordingInProgress

    path = tmp_path / "left.rrd"
    path.write_bytes((ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd").read_bytes()[:head])
    with pytest.raises(ValueError, match=why) as refused:
        read_recording(path)
    assert not isinstance(refused.value, RecordingInProgress)


def test_replay_waits_for_a_recording_being_written_to_hold_its_first_generation(being_started, capsys):
    """The file fills while `lab replay` waits (its writer has started): the viewer opens it."""
    import threading

    example = (ROOT / "recordings" / "examples" / "planar-cmaes-s0.rrd").read_bytes()
    threading.Timer(1.0, being_started.write_bytes, (example,)).start()
    assert cli(["replay", str(being_started), "--web", "--timeout", "1"]) == 0
    out = capsys.readouterr().out
    assert "is being written; waiting for its first generation" in out
    assert "(1000 generations, those written so far: its run is still being recorded)" in out
