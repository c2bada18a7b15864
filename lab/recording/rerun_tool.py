"""The `rerun` command-line tool: where its executable is, and compacting a closed recording with it
(the writer compacts after a clean close; replay merges and shows recordings with it).
"""

from __future__ import annotations

import logging
import os
import subprocess
from pathlib import Path

log = logging.getLogger(__name__)


def rerun_binary() -> str:
    """The real `rerun` executable (the venv's bin/rerun is a Python wrapper around it)."""
    if os.environ.get("RERUN_CLI_PATH"):
        return os.environ["RERUN_CLI_PATH"]
    import rerun_cli

    return str(Path(rerun_cli.__file__).with_name("rerun"))


def compact(path: str | os.PathLike, timeout: float = 60.0) -> bool:
    """Merge a closed recording's many small chunks (`rerun rrd optimize`), in place: about ten
    times smaller, same data. Leaves the file as it was (and returns False) if that fails."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.compacting.rrd")
    try:
        done = subprocess.run([rerun_binary(), "rrd", "optimize", str(path), "-o", str(tmp)],
                              capture_output=True, text=True, timeout=timeout)
        if done.returncode == 0 and tmp.is_file() and tmp.stat().st_size > 0:
            os.replace(tmp, path)
            return True
        log.warning("could not compact %s: %s", path, done.stderr.strip()[-500:])
    except (OSError, subprocess.SubprocessError) as e:
        log.warning("could not compact %s: %s", path, e)
    tmp.unlink(missing_ok=True)
    return False
