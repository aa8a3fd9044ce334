"""A run's scenario with its verdict: the ``prepare`` of :func:`compare.run.run_scenario` for campaigns and the CLI.

With ``[oracle] enabled`` the realized scenario gets its verdict (:mod:`compare.campaign.verdict`),
the witness runs cached in the run directory; the avoidable family redraws until a draw is
labelled ``avoidable`` (:mod:`compare.campaign.avoidable`). Without it, the scenario alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import robots
from compare.campaign.avoidable import realize_avoidable
from compare.campaign.verdict import run_verdict
from compare.config import Config
from compare.scenarios.random_scenario import realize

ORACLE_CACHE_DIR = "oracle"
"""Sub-directory of a run directory caching its witness runs (``<key>.json``)."""


def realize_with_verdict(config: Config, robot: robots.Robot, out_dir: Path) -> tuple[Config, dict[str, Any] | None]:
    """The concrete scenario and, with ``[oracle] enabled``, its verdict (witness runs cached in ``out_dir``)."""
    if not config.oracle.enabled:
        return realize(config, robot), None
    cache = Path(out_dir) / ORACLE_CACHE_DIR
    if config.oracle.avoidable_only and config.scenario.kind == "random":
        return realize_avoidable(config, robot, cache)
    config = realize(config, robot)
    return config, run_verdict(config, robot, cache)
