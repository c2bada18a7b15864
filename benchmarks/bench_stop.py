"""How long the app takes to stop during a run: `python -m app` with a Rerun recording, Start
pressed by a headless tab, then a signal after a few seconds of training; the time from the
signal to the process's exit (the run noted as stopped, its recording closed, the server down).

    .venv/bin/python benchmarks/bench_stop.py [--signals SIGTERM,SIGINT,SIGHUP] [--train 4]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from app.probe import Probe  # noqa: E402


def stop_seconds(sig: str, train: float, folder: str) -> float:
    proc = subprocess.Popen([sys.executable, "-m", "app", "--port", "0", "--notebook", f"{folder}/nb.db",
                             "--recordings", f"{folder}/rec"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    url = next(line.rsplit(" ", 1)[-1].strip() for line in proc.stdout if "Neuro-IK Lab ready" in line)
    probe = Probe(url).start()
    probe.wait_for(lambda m: m.get("name") == "/tab/goal0/label")
    probe.click("Start")
    time.sleep(train)
    probe.close()
    t0 = time.monotonic()
    proc.send_signal(getattr(signal, sig))
    proc.wait(120)  # the app's own exit (its Rerun writer, which shares its stderr, may still be finishing the file)
    seconds = time.monotonic() - t0
    proc.communicate(timeout=120)
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--signals", default="SIGTERM,SIGINT,SIGHUP")
    ap.add_argument("--train", type=float, default=4.0, help="seconds of training before the signal")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        for sig in args.signals.split(","):
            print(f"{sig}: {stop_seconds(sig, args.train, folder):.2f} s from the signal to the app's exit "
                  f"(load average {os.getloadavg()[0]:.1f})", flush=True)


if __name__ == "__main__":
    main()
