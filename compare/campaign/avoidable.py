"""The avoidable family: random draws kept only where the run is labelled ``avoidable``.

With ``[oracle] avoidable_only = true`` (``configs/random_avoidable.toml``), each run's scenario
is drawn as in the random family (:func:`compare.scenarios.random_scenario.realize`), then its
verdict is computed (:func:`compare.campaign.verdict.run_verdict`, every witness stopping at its
first threshold passed); a draw that no witness holds is rejected and the seed is drawn again
(``draw`` 1, 2, …), up to ``max_draws`` times. The run's ``summary.json["oracle"]`` records
``draws`` (draws tried, the kept one included) and ``avoidable_draw_found``; the sweep report
gives the rejection rate.

Every method then faces a scenario in which a motion within its limits that keeps every
threshold is known to exist: an obstacle violation there is the controller's.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import robots
from compare.campaign.verdict import run_verdict
from compare.config import Config
from compare.scenarios.random_scenario import realize

log = logging.getLogger(__name__)


def realize_avoidable(config: Config, robot: robots.Robot, cache_dir: Path | None) -> tuple[Config, dict[str, Any]]:
    """The first draw of ``config.scenario.seed`` labelled ``avoidable``.

    Args:
        config: A random family with ``oracle.avoidable_only``.
        robot: The arm.
        cache_dir: Where the witness runs of the draws are cached (None: not cached).

    Returns:
        The realized scenario and its verdict (``draws``, ``draw``, ``avoidable_draw_found``
        added). When no draw of ``max_draws`` is avoidable, the last one is returned, marked.
    """
    draws = config.oracle.max_draws
    for draw in range(draws):
        candidate = realize(config, robot, draw=draw)
        last = draw == draws - 1
        verdict = run_verdict(candidate, robot, cache_dir, stop_at_violation=True, certificate=last)
        if verdict["label"] == "avoidable" or last:
            break
    found = verdict["label"] == "avoidable"
    if not found:
        log.warning("seed %d: no avoidable draw in %d; the last one is kept", config.scenario.seed, draws)
    verdict.update(draws=draw + 1, avoidable_draw_found=found, draw=draw)
    return candidate, verdict
