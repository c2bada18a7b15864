"""How long a first Start waits on a cold lab: `python -m app` with an empty numba cache (a fresh
NUMBA_CACHE_DIR, as on a fresh clone), a headless tab that presses Start as soon as its page has
come, and the times, from the command, of: the page served ("ready"), each line the app prints (its
warm-up steps), the tab's first status line that names the wait, and the run's first generation.

    .venv/bin/python benchmarks/bench_first_start.py            # cold: an empty numba cache
    .venv/bin/python benchmarks/bench_first_start.py --warm     # numba's own cache (__pycache__)
    .venv/bin/python benchmarks/bench_first_start.py --sigint   # also Ctrl-C during the warm-up: s to exit
    .venv/bin/python benchmarks/bench_first_start.py --busy 1   # beside 1 CPU-bound process (a busy box)
    .venv/bin/python benchmarks/bench_first_start.py --robot ur5

Each warm-up step the app printed is listed with its estimate and the seconds it took (the next line's
time less its own), so the estimates can be judged against what happened.

The shared cache under __pycache__ is never touched: a cold start compiles into a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from app.probe import Probe  # noqa: E402


def busy(n: int) -> list[subprocess.Popen]:
    """n CPU-bound processes (a pure-Python loop each), as another user's work on the box."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def estimates(lines: list[tuple[float, str]]) -> list[str]:
    """Each warm-up step the app printed: its estimate against the seconds it took."""
    out = []
    for k, (t, line) in enumerate(lines):
        m = re.search(r"step (\d+) of (\d+), (.*) \((about (\d+) s|no estimate yet)\)", line)
        after = [u for u, text in lines[k + 1:] if "training kernels" in text]  # the next step, or ready
        if m and after:
            took = after[0] - t
            said = f"estimated {m.group(5)} s" if m.group(5) else "no estimate"
            out.append(f"  step {m.group(1)} of {m.group(2)} ({m.group(3)}): {said}, took {took:.1f} s")
    return out


def first_start(cold: bool, sigint: bool, folder: str, robot: str, hogs: int = 0) -> None:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if cold:
        env["NUMBA_CACHE_DIR"] = os.path.join(folder, "numba-cache")
    hogging = busy(hogs)
    try:
        _first_start(cold, sigint, folder, robot, env, hogs)
    finally:
        for p in hogging:
            p.kill()
            p.wait()


def _first_start(cold: bool, sigint: bool, folder: str, robot: str, env: dict, hogs: int) -> None:
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "app", "--port", "0", "--no-record", "--robot", robot,
                             "--notebook", f"{folder}/nb.db"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env)
    lines: list[tuple[float, str]] = []
    url_ready = threading.Event()
    url = []

    def read() -> None:
        for line in proc.stdout:
            lines.append((time.monotonic() - t0, line.rstrip()))
            if "Neuro-IK Lab ready" in line:
                url.append(line.rsplit(" ", 1)[-1].strip())
                url_ready.set()

    threading.Thread(target=read, daemon=True).start()
    if not url_ready.wait(300):
        proc.kill()
        raise SystemExit("the app printed no URL within 300 s")
    probe = Probe(url[0]).start()
    probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label", timeout=120)
    t_page = time.monotonic() - t0
    if sigint:
        time.sleep(1.0)
        t_sig = time.monotonic()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(60)
            exited = f"{time.monotonic() - t_sig:.2f} s"
        except subprocess.TimeoutExpired:
            proc.kill()
            exited = "not within 60 s (killed)"
        probe.close()
        for t, line in lines:
            print(f"  {t:6.1f} s  {line}")
        print(f"Ctrl-C {t_sig - t0:.1f} s after the command, during the warm-up: exited in {exited} "
              f"(load average {os.getloadavg()[0]:.1f})")
        return
    t_click = time.monotonic() - t0
    probe.click("Start")
    said: dict[str, float] = {}

    def seen() -> int:
        best = 0
        for _t, m in list(probe.messages):
            content = (m.get("updates") or {}).get("_markdown") if m.get("type") == "GuiUpdateMessage" else None
            if not isinstance(content, str):
                continue
            if "preparing" in content and "wait" not in said:
                said["wait"] = time.monotonic() - t0
                said["wait_text"] = content.split("\n")[0]
            g = re.search(r"generation (\d+)", content)
            if g and content.startswith("**Running"):
                best = max(best, int(g.group(1)))
        return best

    deadline = time.monotonic() + 300
    while seen() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    t_gen = time.monotonic() - t0
    probe.close()
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()
    time.sleep(0.2)
    for t, line in lines:
        print(f"  {t:6.1f} s  {line}")
    print("\n".join(estimates(lines)))
    beside = f" beside {hogs} CPU-bound process{'es' if hogs > 1 else ''}" if hogs else ""
    print(f"{'cold' if cold else 'warm'} numba cache{beside}, {robot}: page at {t_page:.1f} s, Start pressed at "
          f"{t_click:.1f} s, first generation at {t_gen:.1f} s: the first Start waited {t_gen - t_click:.1f} s"
          + (f"; the tab named the wait at {said['wait']:.1f} s ({said['wait_text']!r})" if "wait" in said else
             "; the tab never named a wait") + f" (load average {os.getloadavg()[0]:.1f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--warm", action="store_true", help="numba's own cache instead of an empty one")
    ap.add_argument("--sigint", action="store_true", help="Ctrl-C a second after the page came, instead of Start")
    ap.add_argument("--robot", default="planar")
    ap.add_argument("--busy", type=int, default=0, metavar="N", help="CPU-bound processes beside the app (default 0)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        first_start(not args.warm, args.sigint, folder, args.robot, args.busy)


if __name__ == "__main__":
    main()
