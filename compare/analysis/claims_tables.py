"""The paper's claims as Markdown tables, from the JSON form ``tpik-compare paper-claims`` writes.

``claims.json`` is ``{case: {variant: {method: {claim key: {"holds", "runs": [claim dicts]}}}}}``
(:func:`compare.campaign.paper_claims.claims_json`). One table per case: a row per claim, a column
per method, each cell ``case config / paper-paced`` with ✓ when the claim held in the run of every
seed, ✗ otherwise, – when not measured.
"""

from __future__ import annotations

from typing import Any

VARIANTS = ("case config", "paper-paced")
"""The two halves of every cell, in order."""


def claims_markdown(data: dict[str, Any]) -> str:
    """One Markdown table per case of ``data`` (module docstring), separated by a blank line."""
    lines: list[str] = []
    for kind, variants in data.items():
        methods = list(dict.fromkeys(m for per in variants.values() for m in per))
        rows: dict[str, str] = {}
        for per in variants.values():
            for claims in per.values():
                for key, entry in claims.items():
                    runs = entry.get("runs") or [{}]
                    rows.setdefault(key, str(runs[0].get("claim", key)))
        if lines:
            lines.append("")
        lines.append(f"| {kind} claim | " + " | ".join(methods) + " |")
        lines.append("|---|" + "---|" * len(methods))
        for key, text in rows.items():
            cells = []
            for method in methods:
                marks = []
                for variant in VARIANTS:
                    entry = variants.get(variant, {}).get(method, {}).get(key)
                    marks.append("–" if entry is None else "✓" if entry["holds"] else "✗")
                cells.append(" / ".join(marks))
            lines.append(f"| {text} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
