"""The paper's claims of Sec. IV, regenerated on today's code by one command (``tpik-compare paper-claims``).

Runs the paper's two case studies as their configs state them (``configs/case1.toml``,
``configs/case2.toml``: depth sensing, the configs' methods) and their paper-paced variants
(``configs/case1_paper.toml``, ``configs/case2_paper.toml``), for each seed asked, checks every
claim of :mod:`compare.analysis.claims` on every method's run, and writes one table per case:
a cell is "✓" when the claim held in every seed's run, "✗" otherwise, for the case config and
the paper-paced variant (``✓ / ✗``). The case configs have no sensor noise, so every seed gives
the same run; seeds matter once ``[sensor] noise_std_m`` or ``dropout`` is set.

A run directory already holding every method's results of the same config text is reused.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from compare.analysis.claims import Claim, claims_for_run
from compare.analysis.claims_tables import claims_markdown
from compare.analysis.results import CONFIG_FILE, SUMMARY_FILE
from compare.campaign.realize import realize_with_verdict
from compare.config import Config, load_config
from compare.run import run_scenario

CASES: tuple[tuple[str, str], ...] = (
    ("case1.toml", "case config"),
    ("case1_paper.toml", "paper-paced"),
    ("case2.toml", "case config"),
    ("case2_paper.toml", "paper-paced"),
)
"""The configs run, and the column each gives in the tables."""


@dataclass(frozen=True)
class ClaimRuns:
    """One claim of one method in one variant over the seeds' runs.

    Attributes:
        claims: The claim as measured in each seed's run, in seed order.
    """

    claims: tuple[Claim, ...]

    @property
    def holds(self) -> bool:
        """The claim held in every run."""
        return bool(self.claims) and all(c.holds for c in self.claims)


def _run(config: Config, text: str, run_dir: Path, progress: bool) -> None:
    stored = run_dir / CONFIG_FILE
    summary = run_dir / SUMMARY_FILE
    if stored.is_file() and summary.is_file() and stored.read_text(encoding="utf-8") == text:
        done = json.loads(summary.read_text(encoding="utf-8")).get("methods") or {}
        if all(m in done for m in config.methods.names):
            return
    run_scenario(
        config,
        run_dir,
        config_text=text,
        progress=progress,
        make_plots=False,
        overwrite=True,
        prepare=realize_with_verdict,
    )


def run_paper_claims(
    config_dir: Path,
    out_dir: Path,
    seeds: Sequence[int] = (0,),
    methods: Sequence[str] | None = None,
    progress: bool = True,
    announce: Callable[[str], None] | None = None,
    overrides: Mapping[str, object] | None = None,
) -> dict[str, dict[str, dict[str, ClaimRuns]]]:
    """Run every config of :data:`CASES` for every seed and measure the claims.

    Args:
        config_dir: Where the case configs are (``configs/``).
        out_dir: Run directories go to ``out_dir/<config stem>/seed<k>``.
        seeds: Scenario seeds.
        methods: Methods (default: each config's own).
        progress: Progress bars of the runs.
        announce: Called with a line before each run.
        overrides: Dotted config keys set in every case (``{"prediction.mode": "estimated"}``).

    Returns:
        ``{case kind: {variant: {method: {claim key: ClaimRuns}}}}``.
    """
    out: dict[str, dict[str, dict[str, dict[str, list[Claim]]]]] = {}
    for name, variant in CASES:
        for seed in seeds:
            config, text = load_config(Path(config_dir) / name, {**(overrides or {}), "scenario.seed": int(seed)})
            if methods:
                config = config.model_copy(
                    update={"methods": config.methods.model_copy(update={"names": list(methods)})}
                )
            run_dir = Path(out_dir) / Path(name).stem / f"seed{seed}"
            if announce is not None:
                announce(f"{name} seed {seed} → {run_dir}")
            _run(config, text, run_dir, progress)
            per_method = claims_for_run(run_dir, config.methods.names)
            case = out.setdefault(config.scenario.kind, {}).setdefault(variant, {})
            for method, claims in per_method.items():
                for claim in claims:
                    case.setdefault(method, {}).setdefault(claim.key, []).append(claim)
    return {
        kind: {
            variant: {m: {k: ClaimRuns(tuple(v)) for k, v in per.items()} for m, per in methods_.items()}
            for variant, methods_ in variants.items()
        }
        for kind, variants in out.items()
    }


def claims_tables(results: dict[str, dict[str, dict[str, ClaimRuns]]], seeds: Sequence[int]) -> str:
    """One Markdown table per case: rows the claims, columns the methods, cells ``case config / paper-paced``."""
    seed_text = ", ".join(str(s) for s in seeds)
    return (
        claims_markdown(claims_json(results))
        + f"\n\n(each cell: the case config / the paper-paced variant; ✓ = held in the run of every seed ({seed_text}))"
    )


def claims_details(results: dict[str, dict[str, dict[str, ClaimRuns]]]) -> str:
    """What was measured, per case, variant, method and claim (Markdown)."""
    lines = ["| case | variant | method | claim | held | measured (per seed) |", "|---|---|---|---|---|---|"]
    for kind, variants in results.items():
        for variant, per in variants.items():
            for method, claims in per.items():
                for key, runs in claims.items():
                    measured = " ; ".join(c.measured for c in runs.claims).replace("|", "\\|")
                    lines.append(
                        f"| {kind} | {variant} | {method} | {key} | {'✓' if runs.holds else '✗'} | {measured} |"
                    )
    return "\n".join(lines)


def claims_json(results: dict[str, dict[str, dict[str, ClaimRuns]]]) -> dict[str, Any]:
    """JSON-ready form: ``{kind: {variant: {method: {key: {"holds", "runs": [claim dicts]}}}}}``."""
    return {
        kind: {
            variant: {
                method: {k: {"holds": r.holds, "runs": [c.to_dict() for c in r.claims]} for k, r in claims.items()}
                for method, claims in per.items()
            }
            for variant, per in variants.items()
        }
        for kind, variants in results.items()
    }
