"""What a sweep directory is: ``sweep_manifest.json``, written before its first run.

The manifest records the sweep's configuration (its :mod:`compare.config_hash` fingerprint and
hash: everything but ``[methods]``, so the scenario family, the plant — simulation, joint drive,
sensing — and the first seed), the number of runs, the methods and their settings, and the
project version. Re-running ``tpik-compare sweep`` into the directory resumes it only when it is
the same sweep (:func:`check_resume`):

* the same configuration and project version, else refused with one line naming what differs;
* more runs (a larger ``--n``) extend it; fewer run only the first ``n``;
* other methods are added to it (the missing (run, method) pairs are run); a method it already
  has must keep its settings.

``--overwrite`` discards the directory's sweep first (:func:`clear_sweep`); another ``--out``
starts a new one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from compare.analysis.atomic_files import remove_stale_temporaries, write_json_atomic
from compare.analysis.exceptions import ResultsConflict
from compare.analysis.results import (
    CONFIG_FILE,
    MANIFEST_FILE,
    PLOTS_DIR,
    RUNS_DIR,
    SUMMARY_FILE,
    SWEEP_REPORT_FILE,
    SWEEP_RUNS_FILE,
    SWEEP_SUMMARY_FILE,
    git_commit,
    project_version,
)
from compare.config import Config
from compare.config_hash import config_fingerprint, describe_differences, fingerprint_hash, method_settings

FORMAT = 1
"""Version of the manifest layout."""

PLANT_KEYS = ("scenario.sensing", "scenario.simulation", "scenario.drive", "scenario.drive_bandwidth_rad_s")
"""Fingerprint keys that describe the plant the runs are simulated with."""

_HINT = "use another --out for a new sweep, or --overwrite to discard this one"


def make_manifest(config: Config, n: int, methods: list[str]) -> dict[str, Any]:
    """The manifest of a sweep of ``n`` runs of ``config`` with ``methods``."""
    fingerprint = config_fingerprint(config)
    commit = git_commit()
    return {
        "format": FORMAT,
        "config_hash": fingerprint_hash(fingerprint),
        "config_fingerprint": fingerprint,
        "scenario": config.scenario.name,
        "plant": {k.split(".", 1)[1]: fingerprint.get(k) for k in PLANT_KEYS},
        "seed_start": int(config.scenario.seed),
        "runs": int(n),
        "methods": list(methods),
        "method_settings": {m: method_settings(config, m) for m in methods},
        "versions": {"project": project_version(), **({"git_commit": commit} if commit else {})},
    }


def run_config_hash(manifest: dict[str, Any], index: int) -> str:
    """Config hash of run ``index``: the sweep's fingerprint with ``scenario.seed = seed_start + index``.

    Equal to :func:`compare.config_hash.config_hash` of the seeded configuration the run is
    simulated with, without building it.
    """
    fingerprint = dict(manifest["config_fingerprint"])
    fingerprint["scenario.seed"] = int(manifest["seed_start"]) + int(index)
    return fingerprint_hash(fingerprint)


def load_manifest(out_dir: Path) -> dict[str, Any] | None:
    """The manifest of ``out_dir``, or None when it has none.

    Raises:
        ResultsConflict: Unreadable manifest, or a directory that holds a sweep without one
            (written by an older version) or a single run.
    """
    out_dir = Path(out_dir)
    path = out_dir / MANIFEST_FILE
    if not path.exists():
        if (out_dir / RUNS_DIR).is_dir() or (out_dir / SWEEP_SUMMARY_FILE).exists():
            raise ResultsConflict(f"{out_dir} holds a sweep without {MANIFEST_FILE} (older version); {_HINT}")
        if (out_dir / SUMMARY_FILE).exists():
            raise ResultsConflict(f"{out_dir} holds a single run, not a sweep; give the sweep its own --out")
        return None
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ResultsConflict(f"{path} is unreadable ({type(exc).__name__}); {_HINT}") from None
    if not isinstance(manifest, dict) or "config_hash" not in manifest:
        raise ResultsConflict(f"{path} is not a sweep manifest; {_HINT}")
    return manifest


def check_resume(old: dict[str, Any], new: dict[str, Any], out_dir: Path) -> None:
    """Refuse to resume the sweep ``old`` as ``new`` unless it is the same sweep (module docstring).

    Raises:
        ResultsConflict: One line saying what differs.
    """
    old_version = (old.get("versions") or {}).get("project")
    new_version = new["versions"]["project"]
    if old_version != new_version:
        raise ResultsConflict(f"{out_dir} was started with tpik-compare {old_version}, this is {new_version}; {_HINT}")
    if old.get("config_hash") != new["config_hash"]:
        old_fp = old.get("config_fingerprint") or {}
        new_fp = new["config_fingerprint"]
        changed = describe_differences(old_fp, new_fp)
        plant = [k for k in PLANT_KEYS if old_fp.get(k) != new_fp.get(k)]
        what = "plant" if plant else "config"
        raise ResultsConflict(f"{out_dir} holds a sweep with another {what} ({changed}); {_HINT}")
    old_settings = old.get("method_settings") or {}
    for method, settings in new["method_settings"].items():
        if method in old_settings and old_settings[method] != settings:
            raise ResultsConflict(
                f"{out_dir} ran {method} with other settings "
                f"({json.dumps(old_settings[method])} → {json.dumps(settings)}); {_HINT}"
            )


def merge_manifests(old: dict[str, Any] | None, new: dict[str, Any]) -> dict[str, Any]:
    """The manifest after a resume: the union of the methods, the larger number of runs."""
    if old is None:
        return new
    merged = dict(old)
    merged["runs"] = max(int(old.get("runs") or 0), new["runs"])
    known = list(old.get("methods") or [])
    merged["methods"] = known + [m for m in new["methods"] if m not in known]
    merged["method_settings"] = {**new["method_settings"], **(old.get("method_settings") or {})}
    return merged


def write_manifest(out_dir: Path, manifest: dict[str, Any]) -> None:
    """Write ``out_dir/sweep_manifest.json`` atomically."""
    write_json_atomic(Path(out_dir) / MANIFEST_FILE, manifest)


def clear_sweep(out_dir: Path) -> None:
    """Remove a sweep's results from ``out_dir`` (``--overwrite``); other files are left alone."""
    out_dir = Path(out_dir)
    for name in (MANIFEST_FILE, SWEEP_SUMMARY_FILE, SWEEP_RUNS_FILE, SWEEP_REPORT_FILE, CONFIG_FILE):
        (out_dir / name).unlink(missing_ok=True)
    for name in (RUNS_DIR, PLOTS_DIR):
        shutil.rmtree(out_dir / name, ignore_errors=True)
    remove_stale_temporaries(out_dir)
