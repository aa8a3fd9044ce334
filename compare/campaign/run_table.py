"""A setup's runs as one file that outlives its sweep directories (``LABEL.csv`` + ``LABEL.json``).

The table holds a row per (seed, method) with :data:`COLUMNS`, read from each run's
``summary.json`` (ground-truth distances) by :func:`sweep_runs`. The JSON beside it says what the
rows were simulated with: the sweep manifest's configuration fingerprint without the first seed,
the plant, each method's settings, and the sources (sweep directory, project version, git commit,
seeds). A campaign split over several sweeps, or over machines, is kept and grown this way:
:func:`merge_tables` unions tables of one setup and refuses

* another configuration (a fingerprint key both sides have, ``scenario.seed`` aside, with other
  values) or other settings of a method both ran: one line naming the difference;
* a (seed, method) both hold with different rows: a simulation is a function of (config, seed),
  so a difference means the code changed the trajectories, and the seed and method are named.
  Rows compare exactly (NaN equal to NaN); the CSV stores floats with round-trip precision.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from compare.analysis.atomic_files import write_text_atomic
from compare.analysis.exceptions import ResultsConflict
from compare.analysis.results import MANIFEST_FILE, RUNS_DIR, load_summary, write_json_atomic
from compare.campaign.manifest import load_manifest

FORMAT = 1
"""Version of the table's layout."""

COLUMNS = [
    "seed",
    "method",
    "held",
    "label",
    "joint_violation",
    "wall_violation",
    "joint_margin",
    "wall_margin",
    "ee_error_mean",
    "waypoints",
    "physical_time_s",
    "waypoint_times",
    "torso_speed_mps",
]
"""A row: seed, method, held (no obstacle violation), the verdict's label, joint / wall violation
flags and worst margins [rad] / [m], mean EE error [m], waypoints reached, time below the physical
obstacle threshold [s], time to each waypoint [s] (NaN: not reached), the person's peak torso speed
[m/s]."""

_BOOL = ("held", "joint_violation", "wall_violation")
_FLOAT = ("joint_margin", "wall_margin", "ee_error_mean", "waypoints", "physical_time_s", "torso_speed_mps")
SEED_KEY = "scenario.seed"


@dataclass
class RunTable:
    """Rows of one setup (:data:`COLUMNS`) and what they were simulated with (module docstring)."""

    rows: pd.DataFrame
    provenance: dict[str, Any] = field(default_factory=dict)
    inputs: list[str] = field(default_factory=list)
    """The directories and files the rows were loaded from (the provenance goes back further)."""

    @property
    def sources(self) -> list[str]:
        """Where the rows came from: sweep directories or table files."""
        return [str(s.get("from")) for s in self.provenance.get("sources") or []]


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def sweep_runs(sweep_dir: Path) -> pd.DataFrame:
    """One row per (seed, method) of a sweep (:data:`COLUMNS`); unreadable runs are skipped.

    Raises:
        FileNotFoundError: ``sweep_dir`` has no ``runs/`` directory.
    """
    runs_dir = Path(sweep_dir) / RUNS_DIR
    if not runs_dir.is_dir():
        raise FileNotFoundError(f"{sweep_dir}: no {RUNS_DIR}/ directory (not a sweep)")
    rows: list[dict[str, Any]] = []
    for run_dir in sorted(p for p in runs_dir.iterdir() if p.is_dir()):
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):
            continue
        label = (summary.get("oracle") or {}).get("label")
        speeds = (summary.get("person") or {}).get("max_speed_mps") or {}
        for method, m in (summary.get("methods") or {}).items():
            joints, walls = m.get("joint_limits") or {}, m.get("walls") or {}
            rows.append(
                {
                    "seed": summary.get("seed"),
                    "method": method,
                    "held": int((m.get("obstacles") or {}).get("violations") or 0) == 0,
                    "label": label,
                    "joint_violation": int(joints.get("violations") or 0) > 0,
                    "wall_violation": int(walls.get("violations") or 0) > 0,
                    "joint_margin": _number(joints.get("safety_margin_min")),
                    "wall_margin": _number(walls.get("safety_margin_min")),
                    "ee_error_mean": _number((m.get("ee_error_m") or {}).get("mean")),
                    "waypoints": _number(m.get("waypoints_reached")),
                    "physical_time_s": _number((m.get("obstacles") or {}).get("physical_violation_time_s")),
                    "waypoint_times": [_number(t) for t in m.get("time_to_waypoint_s") or []],
                    "torso_speed_mps": _number(speeds.get("torso")),
                }
            )
    return pd.DataFrame(rows, columns=COLUMNS)


def _seed_span(rows: pd.DataFrame) -> list[int]:
    return [int(rows["seed"].min()), int(rows["seed"].max())] if len(rows) else []


def sweep_table(sweep_dir: Path) -> RunTable:
    """A sweep directory's runs with the provenance of its ``sweep_manifest.json`` (none without one).

    Raises:
        FileNotFoundError: ``sweep_dir`` has no ``runs/`` directory.
        ValueError: An unreadable manifest.
    """
    rows = sweep_runs(sweep_dir)
    source: dict[str, Any] = {"from": str(sweep_dir), "seeds": _seed_span(rows), "rows": len(rows)}
    manifest_path = Path(sweep_dir) / MANIFEST_FILE
    if not manifest_path.exists():
        return RunTable(rows, {"format": FORMAT, "sources": [source]})
    try:
        manifest = load_manifest(sweep_dir) or {}
    except ResultsConflict as exc:
        raise ValueError(str(exc)) from None
    fingerprint = {k: v for k, v in (manifest.get("config_fingerprint") or {}).items() if k != SEED_KEY}
    versions = manifest.get("versions") or {}
    source.update({"project_version": versions.get("project"), "git_commit": versions.get("git_commit")})
    provenance = {
        "format": FORMAT,
        "scenario": manifest.get("scenario"),
        "plant": manifest.get("plant"),
        "method_settings": manifest.get("method_settings") or {},
        "config_fingerprint": fingerprint,
        "sources": [source],
    }
    return RunTable(rows, provenance)


def _encode_times(times: list[float]) -> str:
    return ";".join(repr(float(t)) for t in times)


def _decode_times(text: Any) -> list[float]:
    if not isinstance(text, str) or not text:
        return []
    return [float(t) for t in text.split(";")]


def write_table(table: RunTable, path: Path) -> tuple[Path, Path]:
    """Write ``path`` (``.csv``, rows sorted by seed and method) and its provenance (``.json``)."""
    path = Path(path)
    rows = table.rows.sort_values(["seed", "method"], kind="stable").copy()
    rows["waypoint_times"] = rows["waypoint_times"].map(_encode_times)
    rows["label"] = rows["label"].fillna("")
    meta = path.with_suffix(".json")
    write_text_atomic(path, rows.to_csv(index=False, columns=COLUMNS, na_rep="nan"))
    write_json_atomic(meta, table.provenance)
    return path, meta


def read_table(path: Path) -> RunTable:
    """A table written by :func:`write_table`.

    Raises:
        FileNotFoundError: No such file.
        ValueError: Missing columns or an unreadable file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        text = pd.read_csv(path, dtype=str, keep_default_na=False)
        missing = [c for c in COLUMNS if c not in text.columns]
        if missing:
            raise ValueError(f"not a run table (missing columns {', '.join(missing)})")
        # Python's float() of repr() is exact; pandas' own float parsing is not guaranteed to be.
        rows = pd.DataFrame(
            {
                "seed": [int(v) for v in text["seed"]],
                "method": list(text["method"]),
                **{c: [v.strip().lower() == "true" for v in text[c]] for c in _BOOL},
                "label": [v or None for v in text["label"]],
                **{c: [float(v) for v in text[c]] for c in _FLOAT},
                "waypoint_times": [_decode_times(v) for v in text["waypoint_times"]],
            }
        )[COLUMNS]
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: unreadable ({exc})") from None
    meta = path.with_suffix(".json")
    provenance: dict[str, Any] = {"format": FORMAT, "sources": [{"from": str(path)}]}
    if meta.is_file():
        try:
            provenance = json.loads(meta.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ValueError(f"{meta}: unreadable ({type(exc).__name__})") from None
    return RunTable(rows.reset_index(drop=True), provenance)


def load_table(path: Path) -> RunTable:
    """A sweep directory (:func:`sweep_table`) or a table file (:func:`read_table`)."""
    table = sweep_table(path) if Path(path).is_dir() else read_table(path)
    table.inputs = [str(path)]
    return table


def _shown(value: Any) -> str:
    """A cell for an error message: plain Python values, not numpy's reprs."""
    return repr(value.item() if hasattr(value, "item") else value)


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, list) or isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    missing_a, missing_b = (
        a is None or (isinstance(a, float) and math.isnan(a)),
        b is None or (isinstance(b, float) and math.isnan(b)),
    )
    if missing_a or missing_b:
        return missing_a and missing_b
    return bool(a == b)


def _check_compatible(a: dict[str, Any], b: dict[str, Any], what: str) -> None:
    fa, fb = a.get("config_fingerprint") or {}, b.get("config_fingerprint") or {}
    changed = sorted(k for k in set(fa) & set(fb) if k != SEED_KEY and fa[k] != fb[k])
    if changed:
        diffs = ", ".join(f"{k}: {json.dumps(fa[k])} → {json.dumps(fb[k])}" for k in changed[:3])
        more = f" and {len(changed) - 3} more" if len(changed) > 3 else ""
        raise ValueError(f"{what}: simulated with another configuration ({diffs}{more})")
    sa, sb = a.get("method_settings") or {}, b.get("method_settings") or {}
    for method in set(sa) & set(sb):
        if sa[method] != sb[method]:
            before, after = json.dumps(sa[method]), json.dumps(sb[method])
            raise ValueError(f"{what}: {method} ran with other settings ({before} → {after})")


def _add_sources(kept: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``kept`` then ``new``; a kept source that a new one repeats (the same sweep, grown since) is dropped."""

    def same_sweep(a: dict[str, Any], b: dict[str, Any]) -> bool:
        keys = ("from", "project_version", "git_commit")
        inside = (
            bool(a.get("seeds"))
            and bool(b.get("seeds"))
            and b["seeds"][0] <= a["seeds"][0] <= a["seeds"][-1] <= b["seeds"][-1]
        )
        return all(a.get(k) == b.get(k) for k in keys) and inside

    return [k for k in kept if not any(same_sweep(k, n) for n in new)] + list(new)


def merge_tables(tables: list[RunTable], what: str = "runs") -> RunTable:
    """The union of ``tables`` of one setup (module docstring); ``what`` names the setup in errors.

    Raises:
        ValueError: Another configuration or method settings, or one (seed, method) with two
            different rows.
    """
    if not tables:
        raise ValueError(f"{what}: no runs")
    merged = RunTable(tables[0].rows.copy(), json.loads(json.dumps(tables[0].provenance)), list(tables[0].inputs))
    for table in tables[1:]:
        _check_compatible(merged.provenance, table.provenance, what)
        old = merged.rows.set_index(["seed", "method"])
        new = table.rows.set_index(["seed", "method"])
        for key in old.index.intersection(new.index):
            a, b = old.loc[key], new.loc[key]
            for column in old.columns:
                if not _same(a[column], b[column]):
                    raise ValueError(
                        f"{what}: seed {key[0]}, {key[1]} differs between {' + '.join(merged.sources)} and "
                        f"{' + '.join(table.sources)} ({column}: {_shown(a[column])} vs {_shown(b[column])}); "
                        "the simulation changed"
                    )
        fresh = table.rows[~new.index.isin(old.index)]
        merged.rows = pd.concat([merged.rows, fresh], ignore_index=True)
        meta = merged.provenance
        for key in ("scenario", "plant"):
            meta.setdefault(key, table.provenance.get(key))
        meta["method_settings"] = {
            **(table.provenance.get("method_settings") or {}),
            **(meta.get("method_settings") or {}),
        }
        meta["config_fingerprint"] = {
            **(table.provenance.get("config_fingerprint") or {}),
            **(meta.get("config_fingerprint") or {}),
        }
        meta["sources"] = _add_sources(meta.get("sources") or [], table.provenance.get("sources") or [])
        merged.inputs += table.inputs
    merged.rows = merged.rows.sort_values(["seed", "method"], kind="stable").reset_index(drop=True)
    return merged
