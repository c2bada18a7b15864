"""The paper's own numbers (Martín H., de Lope and Santos, 2009), as printed, for side-by-side tables.

paper/table3.csv: Table 3, the 30 final training MSEs per arm and method, sorted (columns
`planar_cmaes`, ...). paper/tables4-5.csv: Tables 4 and 5 (t, df, p, decision), where p is the
one-sided p in the observed direction (see stats.py). Only planar/scara x cmaes/neat exist.
"""

from __future__ import annotations

import csv
import functools
import io
from importlib import resources

import numpy as np

AUTHORS = "Martín H., de Lope and Santos"  # José Antonio Martín H., Javier de Lope, Matilde Santos
YEAR = 2009
TITLE = "A method to learn the inverse kinematics of multi-link robots by evolving neuro-controllers"

# The paper's two methods, compared in its Tables 3-5 (x = CMA-ES, y = NEAT in the Welch tests):
# the one place outside lab/methods that names methods.
METHODS = ("cmaes", "neat")


def _read(name: str) -> list[dict]:
    text = resources.files(__package__).joinpath("paper", name).read_text()
    return list(csv.DictReader(io.StringIO(text)))


@functools.cache
def table3() -> dict[tuple[str, str], np.ndarray]:
    """{(robot, method): the paper's 30 final training MSEs, ascending}."""
    rows = _read("table3.csv")
    cols = [c for c in rows[0] if c != "rank"]
    return {tuple(c.split("_", 1)): np.array([float(r[c]) for r in rows]) for c in cols}


@functools.cache
def tests() -> dict[tuple[str, str], dict]:
    """{(robot, "all" | "best10"): {"t", "df", "p", "decision"}} of Tables 4 and 5 as printed."""
    out = {}
    for r in _read("tables4-5.csv"):
        sel = "all" if r["table"] == "4" else "best10"
        out[(r["robot"], sel)] = {"t": float(r["t"]), "df": float(r["df"]), "p": float(r["p"]),
                                  "decision": r["decision"]}
    return out


def column(robot: str, method: str) -> np.ndarray | None:
    return table3().get((robot, method))
