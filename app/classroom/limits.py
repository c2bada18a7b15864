"""What a shared server accepts: settings bounded by what one machine can serve a class with.

The lab's own bounds (lab.running.config.LIMITS: population 10,000, hidden 256, 10^9 generations)
keep one run within one machine, not a class's server beside it (what a run at those bounds costs:
docs/classroom.md). A server reachable beyond loopback (`--host 0.0.0.0`) accepts at most CLASSROOM
instead, which every robot's and method's defaults fit (the real arms: 32 hidden units, 300 goals,
40,000 generations; a tree: 64 hidden units, the gradient method 3,000 goals). A run with a time budget (TrainConfig.seconds) is bounded by its seconds
instead of its generations (UNBOUNDED, 10^9, unless given). `python -m app --limit population=1000`
raises one at start.
"""

from __future__ import annotations

import lab.running.config as config_mod

# name -> the TrainConfig field it bounds, and its classroom value
CLASSROOM = {"population": 200, "hidden": 64, "goals": 3000, "generations": 100_000, "seconds": 600}
FIELD = {"population": "population", "hidden": "hidden", "goals": "targets", "generations": "generations",
         "seconds": "seconds"}
LAB = {"population": config_mod.LIMITS["population"], "hidden": config_mod.LIMITS["hidden"],
       "goals": config_mod.LIMITS["goals"], "generations": 10**9, "seconds": 10**9}


# what a tab calls each setting (the labels of My experiment's and the Train panel's fields), by --limit
# name and by TrainConfig field: a refusal a student or presenter reads names the field they see; the
# Python API's own errors (lab.TrainConfig's) keep the API's names
LABELS = {"population": "Population", "hidden": "Hidden units", "goals": "Goals", "targets": "Goals",
          "generations": "Generations", "seconds": "Time budget (s)", "seed": "Seed"}


def in_labels(text: str) -> str:
    """A refusal in the lab's words ("targets must be an integer in 1..1,000,000, got 0") in the tab's
    ("Goals must be an integer in 1..1,000,000, got 0"): its first word, when that is a field, as its label."""
    name, sep, rest = text.partition(" ")
    return f"{LABELS[name]} {rest}" if sep and name in LABELS else text


def refused(why: str) -> str:
    """"refused: why", saying it once: a reason passed on that already says it (an access refusal) is
    not prefixed again."""
    return why if why.startswith("refused") else f"refused: {why}"


def _shown(text: str, most: int = 40) -> str:
    """text as a message shows it: its repr, cut to `most` characters (a value may be megabytes)."""
    return repr(text) if len(text) <= most else f"{text[:most]!r}... ({len(text):,} characters)"


def parse_limit(text: str) -> tuple[str, int]:
    """'population=1000' -> ('population', 1000); ValueError naming what is wrong (in one short line,
    whatever was given: NaN, inf, 1e400, a number of 5,000 digits)."""
    name, sep, value = text.partition("=")
    name = name.strip()
    if not sep or name not in CLASSROOM:
        raise ValueError(f"--limit takes NAME=N with NAME one of {', '.join(CLASSROOM)}, got {_shown(text)}")
    bound = f"--limit {name}: must be in 1..{LAB[name]:,} (the lab's own bound), got"
    try:
        n = int(value)
    except ValueError:
        digits = value.strip().lstrip("+-")
        if digits.isdigit():  # a whole number beyond Python's 4,300 digits
            raise ValueError(f"{bound} a {'negative ' * value.strip().startswith('-')}number of {len(digits):,} "
                             f"digits") from None
        raise ValueError(f"--limit {name}: a whole number, got {_shown(value)}") from None
    if not 1 <= n <= LAB[name]:
        shown = f"{n:,}" if abs(n) < 10**30 else f"a {'negative ' * (n < 0)}number of {len(str(abs(n))):,} digits"
        raise ValueError(f"{bound} {shown}")
    return name, n


def limits_for(host_is_loopback: bool, raised: dict[str, int] | None = None) -> dict[str, int] | None:
    """The bounds a server applies: None (the lab's own) on loopback unless some are given; beyond
    loopback CLASSROOM with the given ones in place of its values."""
    if host_is_loopback and not raised:
        return None
    return {**CLASSROOM, **(raised or {})}


def refusal(config, limits: dict[str, int] | None) -> str | None:
    """Why this server does not accept config (None: it does)."""
    if not limits:
        return None
    budgeted = getattr(config, "seconds", None) is not None
    for name, most in limits.items():
        if name == "generations" and budgeted:  # the time budget bounds the run (checked as "seconds")
            continue
        value = getattr(config, FIELD[name], None)
        if value is not None and value > most:
            label = LABELS[name]
            shown = f"{value:,}" if isinstance(value, int) else f"{value:g}"
            return (f"{label} must be at most {most:,} on this shared server, got {shown} "
                    f"(start it with --limit {name}=N to raise it)")
    return None
