"""Recordings: one Rerun .rrd file per training run, and reading them back.

- logger.py: RerunLogger, a Runner subscriber that hands every generation to
- writer.py: the writer process (`python -m lab.recording.writer`), which logs it to Rerun;
- views.py: what a recording draws (the arm, the network, the blueprint), per method's kind;
- replay.py: read a recording (`Recording`, `load_controller`), show it in the viewer;
- rerun_tool.py: the `rerun` executable (the viewer, compaction, merging);
- busy.py: whether a recording is being written (a lock its logger and writer process hold).
"""

from lab.recording.logger import RerunLogger, not_a_folder, prepare_path

__all__ = ["RerunLogger", "not_a_folder", "prepare_path"]
