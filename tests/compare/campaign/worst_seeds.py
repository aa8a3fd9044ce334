"""The hard campaign's worst runs, frozen as concrete scenarios (``worst_seeds/*.toml``).

Each case is a seed of ``configs/random.toml`` cut at a time inside its former violation. The
scenario the generator realised for it (start pose, waypoints, person path, sensor noise) is
stored as a ``kind = "scripted"`` config, so the regression test keeps simulating the very
scenario that once failed even if :mod:`compare.scenarios.random_scenario` changes; a separate
test says when the generator no longer reproduces the files. Re-freeze (after checking that the
new scenarios still reach the thresholds the docstring of the test describes) with::

    PYTHONPATH=. python -m tests.compare.campaign.worst_seeds
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

import robots
from compare.config import Config, load_config
from compare.scenarios.random_scenario import realize

ROOT = Path(__file__).resolve().parents[3]
FAMILY = ROOT / "configs" / "random.toml"
FROZEN_DIR = Path(__file__).resolve().parent / "worst_seeds"
REFREEZE = "PYTHONPATH=. python -m tests.compare.campaign.worst_seeds"


@dataclass(frozen=True)
class WorstSeed:
    """One frozen run: ``configs/random.toml`` at ``seed``, cut at ``duration_s``, on ``drive``.

    Attributes:
        seed: Scenario seed.
        method: The method whose run violated.
        duration_s: Where the run is cut [s] (inside the former violation).
        group: The set-task group that was violated.
        drive: Joint drive of the dynamic simulation.
        kept_from_earlier_generator: Why the file keeps a scenario the generator no longer draws
            (None: the generator's draw today is frozen, and the drift test checks it).
    """

    seed: int
    method: str
    duration_s: float
    group: str
    drive: str
    kept_from_earlier_generator: str | None = None

    @property
    def path(self) -> Path:
        """The frozen scenario file."""
        return FROZEN_DIR / f"seed{self.seed}-{self.method}-{self.drive}.toml"

    @property
    def overrides(self) -> dict[str, Any]:
        """What the case changes in the family config."""
        return {"scenario.seed": self.seed, "scenario.duration_s": self.duration_s, "scenario.drive": self.drive}


CASES: tuple[WorstSeed, ...] = (
    WorstSeed(379, "tpik", 13.0, "joint_limits", "servo"),
    WorstSeed(215, "hqp-daqp", 20.0, "walls", "servo"),
    WorstSeed(
        145,
        "tpik",
        18.2,
        "joint_limits",
        "servo",
        "the person's path of this seed changed (speed-limited visits), and with it the arm's state at"
        " 17.9 s: the largest-norm mode choice this case tests no longer happens there",
    ),
    WorstSeed(610, "hqp-daqp", 14.5, "walls", "decoupled"),
    WorstSeed(132, "tpik", 7.3, "walls", "decoupled"),
)


def realized(case: WorstSeed) -> Config:
    """The scenario the generator draws for ``case`` today, as a scripted config of its method."""
    config, _ = load_config(FAMILY, case.overrides)
    concrete = realize(config, robots.load("jaco2"))
    return concrete.model_copy(
        update={
            "scenario": concrete.scenario.model_copy(update={"kind": "scripted", "name": case.path.stem}),
            "methods": concrete.methods.model_copy(update={"names": [case.method], "settings": {}}),
        }
    )


def frozen_view(config: Config) -> dict[str, Any]:
    """What is frozen of a scenario: everything but the unused random ranges and hardware section."""
    return config.model_dump(mode="json", exclude_none=True, exclude={"random", "hardware"})


def freeze_text(case: WorstSeed, config: Config) -> str:
    """The TOML of a frozen case, headed by where it comes from."""
    header = (
        f"# Frozen by tests/compare/campaign/worst_seeds.py: configs/random.toml, seed {case.seed}, cut at\n"
        f"# {case.duration_s:g} s, {case.drive} drive; {case.method} violated {case.group} here.\n"
        f"# Re-freeze: {REFREEZE}\n\n"
    )
    return header + tomli_w.dumps(frozen_view(config))


def main() -> None:
    """Write every case's frozen scenario."""
    FROZEN_DIR.mkdir(exist_ok=True)
    for case in CASES:
        if case.kept_from_earlier_generator:
            continue
        case.path.write_text(freeze_text(case, realized(case)), encoding="utf-8")
        print(case.path.relative_to(ROOT))


if __name__ == "__main__":
    main()
