"""The avoidable family: random draws kept only where the clairvoyant oracle holds the threshold.

With ``[oracle] avoidable_only = true`` (``configs/random_avoidable.toml``), each run's scenario
is drawn as in the random family (:func:`compare.campaign.random_scenario.realize`), then the
oracle (:mod:`compare.campaign.oracle`) is run on it; a draw where the oracle lets a control
point past the obstacle safety threshold is rejected (its oracle run stops at the first
violation) and the seed is drawn again (``draw`` 1, 2, …), up to ``max_draws`` times. The run's
``summary.json["oracle"]`` records ``draws`` (draws tried, the kept one included) and
``avoidable_draw_found``; the sweep report gives the rejection rate.

Every method then faces a scenario in which a trajectory within its limits that keeps the
threshold is known to exist: an obstacle violation there is the controller's (avoidable).
"""

from __future__ import annotations

import logging
from pathlib import Path

import robots
from compare.campaign.oracle import OracleRun, cached_oracle
from compare.campaign.random_scenario import realize
from compare.config import Config

log = logging.getLogger(__name__)


def realize_avoidable(config: Config, robot: robots.Robot, cache_dir: Path | None) -> tuple[Config, OracleRun]:
    """The first draw of ``config.scenario.seed`` in which the oracle holds the safety threshold.

    Args:
        config: A random family with ``oracle.avoidable_only``.
        robot: The arm.
        cache_dir: Where the oracle runs of the draws are cached (None: not cached).

    Returns:
        The realized scenario and its oracle run (``entry["draws"]``, ``entry["avoidable_draw_found"]``
        added). When no draw of ``max_draws`` is avoidable, the last one is returned, marked.
    """
    draws = config.oracle.max_draws
    for draw in range(draws):
        candidate = realize(config, robot, draw=draw)
        run = cached_oracle(candidate, robot, cache_dir, stop_at_violation=True)
        if run.entry.get("held_safety") or draw == draws - 1:
            break
    found = bool(run.entry.get("held_safety"))
    if not found:
        log.warning("seed %d: no avoidable draw in %d; the last one is kept", config.scenario.seed, draws)
    run.entry.update(draws=draw + 1, avoidable_draw_found=found, draw=draw)
    return candidate, run
