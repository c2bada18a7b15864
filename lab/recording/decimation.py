"""Which generations a recording logs: the rules live in lab.running.decimation (the runner
applies them too); named here as well for the recording's readers."""

from lab.running.decimation import (  # noqa: F401
    EVERY_UNTIL, POPULATION_EVERY_FIRST, POPULATION_THEN_EVERY, long_run, long_run_count, population_logged,
)
