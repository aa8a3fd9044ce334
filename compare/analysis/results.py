"""Results directories: ``summary.json``, per-step tables, sweeps (docs/design.md §7).

A run directory holds::

    config.toml              copy of the configuration (when given)
    replay.toml              the concrete scenario that was simulated (random draws resolved),
                             what ``tpik-compare replay`` rebuilds the scene from
    summary.json             {"scenario", "seed", "sim_time_s", "versions", "config_hash",
                              "config_fingerprint", "methods": {...},
                              "replay": {"format", "scenario_file"} (with replay.toml),
                              "errors": {...} (only if a method failed)}
    steps/<method>.parquet   per-step table (``steps/<method>.csv`` if Parquet cannot encode it)
    plots/*.png              written by :mod:`compare.analysis.plots`
    report.md                the results table, links to the plots, a case config's claims
                             (:mod:`compare.analysis.run_report`)

Every file is written atomically (:mod:`compare.analysis.atomic_files`): a killed process leaves
the old file or the new one. A method's per-step table is written before the ``summary.json``
that names it, so a method listed in the summary has its complete table.

**A directory that already holds results** (:class:`ResultsWriter`) either takes the new methods
next to the others — same scenario and configuration (``config_hash``, see
:mod:`compare.config_hash`: everything but ``[methods]``) and same project version:
``summary.json`` is merged per method, the other methods' files are not touched — or is refused
with one line (:class:`ResultsConflict`) naming the conflict: another configuration, a method it
already holds finished results of, a sweep directory, a summary it cannot read. ``overwrite=True``
(``--overwrite``) discards the previous results first. A method whose files are incomplete or
unreadable is not a finished result: it is run again without ``--overwrite``. While a writer is
open the directory is locked (``.tpik-compare.lock``), so two processes never write one directory.

Each method entry is the output of :func:`compare.analysis.metrics.compute_summary`; its
``set_tasks`` list holds the thresholds of every set task (infinite bounds as ``null``), which the
plots read.

A sweep directory holds ``sweep_manifest.json`` (what the sweep is: :mod:`compare.campaign.manifest`),
``runs/<index:05d>/`` run directories, ``sweep_runs.csv`` (one row per run and method),
``sweep_summary.json`` (per-method aggregates), ``plots/`` and ``sweep_report.md``
(:func:`compare.analysis.report.render_sweep_report`).
"""

from __future__ import annotations

import contextlib
import copy
import fcntl
import functools
import json
import logging
import os
import shutil
import subprocess
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from compare.analysis.atomic_files import (
    atomic_write,
    is_temporary,
    remove_stale_temporaries,
    write_json_atomic,
    write_text_atomic,
)
from compare.analysis.exceptions import DirectoryBusy, ResultsConflict
from compare.analysis.metric import SweepRuns, to_jsonable
from compare.analysis.metrics import registered_metrics
from compare.analysis.preflight import check_output_dir
from compare.analysis.statistics import mcnemar
from compare.config_hash import describe_differences
from compare.versions import versions

log = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
STEPS_DIR = "steps"
PLOTS_DIR = "plots"
RUNS_DIR = "runs"
CONFIG_FILE = "config.toml"
REPLAY_FILE = "replay.toml"
REPLAY_FORMAT = 1
"""Version of the replay record (``summary["replay"]["format"]``): raised when a replay needs more."""
SWEEP_SUMMARY_FILE = "sweep_summary.json"
SWEEP_RUNS_FILE = "sweep_runs.csv"
SWEEP_REPORT_FILE = "sweep_report.md"
RUN_REPORT_FILE = "report.md"
MANIFEST_FILE = "sweep_manifest.json"
LOCK_FILE = ".tpik-compare.lock"


def write_steps_parquet(steps: pd.DataFrame, path: Path) -> None:
    """Write a per-step table to ``path`` as Parquet, column by column (no index, no pandas metadata).

    Read back with :func:`pandas.read_parquet` it is the same table (float NaN as null, a fresh
    ``RangeIndex``); built from the columns' arrays it costs about half of ``DataFrame.to_parquet``,
    once per method and run. Only the text columns (status, reason, ...) are dictionary-encoded.

    Raises:
        pyarrow.ArrowException: A column Parquet cannot encode (the caller falls back to CSV).
    """
    names = [str(c) for c in steps.columns]
    arrays = [pa.array(steps[c].to_numpy(), from_pandas=True) for c in steps.columns]
    text = [name for name, array in zip(names, arrays, strict=True) if pa.types.is_string(array.type)]
    table = pa.Table.from_arrays(arrays, names=names)
    pq.write_table(table, path, use_dictionary=text, write_statistics=False)


@functools.cache
def git_commit() -> str | None:
    """Commit of the project checkout (``git rev-parse HEAD``), or None outside a git checkout."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5.0,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit or None


def run_versions() -> dict[str, str]:
    """:func:`compare.versions.versions` plus ``git_commit`` when available."""
    out = dict(versions())
    commit = git_commit()
    if commit is not None:
        out["git_commit"] = commit
    return out


def project_version() -> str:
    """Version of this project (``versions()["project"]``)."""
    return str(versions().get("project"))


def safe_name(method: str) -> str:
    """File-system-safe version of a method key (``hqp-daqp`` stays as it is)."""
    return "".join(c if c.isalnum() or c in "-_.+" else "_" for c in method)


class DirectoryLock:
    """An exclusive advisory lock (``flock``) on ``directory/.tpik-compare.lock``.

    Raises:
        DirectoryBusy: Another process holds it.
    """

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / LOCK_FILE
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._fd)
            self._fd = None
            raise DirectoryBusy(f"{directory} is being written by another tpik-compare process") from None
        except OSError:  # a file system without locks: go on unlocked
            log.debug("no file locks on %s", directory)

    def release(self) -> None:
        """Release the lock (idempotent)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __del__(self) -> None:
        self.release()


def steps_complete(run_dir: Path, entry: Mapping[str, Any]) -> bool:
    """Whether the per-step table a method entry names is there, complete and readable.

    A Parquet file must have a readable footer (a truncated file has none) and, when the entry
    records it, the number of rows written (``steps_rows``).
    """
    rel = entry.get("steps_file")
    if not isinstance(rel, str):
        return False
    path = Path(run_dir) / rel
    if not path.is_file():
        return False
    rows: int | None
    try:
        if path.suffix == ".parquet":
            rows = int(pq.read_metadata(path).num_rows)
        else:
            rows = len(pd.read_csv(path))
    except Exception:  # noqa: BLE001 - whatever the reader raises, the table is not usable
        return False
    expected = entry.get("steps_rows")
    return expected is None or rows == int(expected)


def run_dirs(directory: Path, max_runs: int | None = None) -> list[Path]:
    """The run directories of ``directory``: itself or its sweep's runs, in order.

    A run has ``summary.json`` and no ``runs/``; of a sweep, the runs with a ``summary.json``
    (the first ``max_runs`` when given).
    """
    directory = Path(directory)
    if (directory / SUMMARY_FILE).is_file() and not (directory / RUNS_DIR).is_dir():
        return [directory]
    runs = sorted(p for p in (directory / RUNS_DIR).glob("*") if (p / SUMMARY_FILE).is_file())
    return runs[:max_runs] if max_runs is not None else runs


def finished_methods(run_dir: Path, summary: Mapping[str, Any] | None = None) -> set[str]:
    """Methods of ``run_dir`` whose results are complete: in ``summary.json`` and their table readable.

    A method recorded as an error, or whose table is missing or unreadable, is not finished.
    """
    if summary is None:
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):
            return set()
    methods = summary.get("methods") or {}
    return {m for m, entry in methods.items() if isinstance(entry, dict) and steps_complete(run_dir, entry)}


def read_previous(out_dir: Path) -> dict[str, Any] | None:
    """The ``summary.json`` already in ``out_dir``, or None when there is none.

    Raises:
        ResultsConflict: The file is there but cannot be read as a summary.
    """
    path = Path(out_dir) / SUMMARY_FILE
    if not path.exists():
        return None
    try:
        summary = load_summary(out_dir)
    except (OSError, ValueError) as exc:
        raise ResultsConflict(
            f"{path} is unreadable ({type(exc).__name__}); use --overwrite to replace the directory's results"
        ) from None
    if not isinstance(summary, dict) or not isinstance(summary.get("methods"), dict):
        raise ResultsConflict(f"{path} is not a results summary; use --overwrite to replace it")
    return summary


def clear_run_results(out_dir: Path) -> None:
    """Remove the results of a run directory (``--overwrite``): summary, tables, plots, configs."""
    out_dir = Path(out_dir)
    for name in (SUMMARY_FILE, CONFIG_FILE, REPLAY_FILE):
        (out_dir / name).unlink(missing_ok=True)
    for name in (STEPS_DIR, PLOTS_DIR):
        shutil.rmtree(out_dir / name, ignore_errors=True)
    remove_stale_temporaries(out_dir)


def is_sweep_dir(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds a sweep (a manifest, a sweep summary or ``runs/``)."""
    out_dir = Path(out_dir)
    return any((out_dir / name).exists() for name in (MANIFEST_FILE, SWEEP_SUMMARY_FILE, RUNS_DIR))


class ResultsWriter:
    """Write one run's results method by method, into a new directory or next to earlier results.

    The checks happen here, before anything is simulated: the directory is created and must be
    writable with room for ``expected_bytes`` (:func:`compare.analysis.preflight.check_output_dir`);
    it is locked against other writers; results already in it are kept and merged, or the
    writer refuses (module docstring).

    Args:
        out_dir: Run directory (created with its parents).
        scenario: Scenario name.
        seed: Scenario seed.
        sim_time_s: Simulated duration of the scenario [s].
        config_text: TOML text of the configuration, copied to ``config.toml`` (skipped if None;
            kept as it is when merging).
        config_hash: :func:`compare.config_hash.config_hash` of the configuration; None = unknown
            (such a writer never merges: a directory with results is refused).
        config_fingerprint: :func:`compare.config_hash.config_fingerprint` (names the keys of a
            config conflict).
        methods: The methods about to be added (a finished one already there is a conflict).
        method_settings: ``{method: settings}`` recorded with each method's entry.
        overwrite: Discard the directory's previous results first.
        expected_bytes: Size of the results to come (up-front disk space check).

    Raises:
        ResultsConflict: The directory holds results these would replace or mix with.
        DirectoryBusy: Another process is writing it.
        OutputUnusable: It cannot be created or written, or the disk is too full.
    """

    def __init__(
        self,
        out_dir: Path,
        scenario: str,
        seed: int,
        sim_time_s: float,
        config_text: str | None,
        *,
        config_hash: str | None = None,
        config_fingerprint: Mapping[str, Any] | None = None,
        methods: Iterable[str] = (),
        method_settings: Mapping[str, Mapping[str, Any]] | None = None,
        overwrite: bool = False,
        expected_bytes: int = 0,
    ) -> None:
        self.out_dir = Path(out_dir)
        self._pending = False  # run-level entries set but not written yet (set_run_info)
        check_output_dir(self.out_dir, expected_bytes)
        self._lock: DirectoryLock | None = DirectoryLock(self.out_dir)
        try:
            if is_sweep_dir(self.out_dir):  # even with overwrite: a typo must not cost a campaign
                raise ResultsConflict(f"{self.out_dir} is a sweep directory; give a run its own --out")
            if overwrite:
                clear_run_results(self.out_dir)
            previous = None if overwrite else read_previous(self.out_dir)
            fresh: dict[str, Any] = {
                "scenario": scenario,
                "seed": int(seed),
                "sim_time_s": float(sim_time_s),
                "versions": run_versions(),
                "config_hash": config_hash,
                "config_fingerprint": dict(config_fingerprint) if config_fingerprint is not None else None,
                "methods": {},
            }
            if previous is not None:
                self._check_compatible(previous, fresh, list(methods))
                self._summary = previous
            else:
                if config_text is not None:
                    write_text_atomic(self.out_dir / CONFIG_FILE, config_text)
                self._summary = fresh
            remove_stale_temporaries(self.out_dir)  # a killed writer's; we hold the lock
            remove_stale_temporaries(self.out_dir / STEPS_DIR)
            self._method_settings = {k: dict(v) for k, v in (method_settings or {}).items()}
            self._write()
        except BaseException:
            self.close()
            raise

    def _check_compatible(self, previous: dict[str, Any], fresh: dict[str, Any], methods: list[str]) -> None:
        """Raise :class:`ResultsConflict` unless ``fresh`` may be merged into ``previous``."""
        where = self.out_dir
        hint = "use --overwrite to replace them, or another --out"
        old_hash = previous.get("config_hash")
        if old_hash is None or fresh["config_hash"] is None:
            raise ResultsConflict(
                f"{where} holds results whose configuration cannot be compared (no config hash); {hint}"
            )
        if old_hash != fresh["config_hash"]:
            old_fp, new_fp = previous.get("config_fingerprint"), fresh["config_fingerprint"]
            what = (
                describe_differences(old_fp, new_fp)
                if isinstance(old_fp, dict) and isinstance(new_fp, dict)
                else f"config {str(old_hash)[:12]} → {str(fresh['config_hash'])[:12]}"
            )
            raise ResultsConflict(f"{where} holds results of another configuration ({what}); {hint}")
        old_version = (previous.get("versions") or {}).get("project")
        new_version = fresh["versions"].get("project")
        if old_version != new_version:
            raise ResultsConflict(f"{where} holds results of tpik-compare {old_version}, this is {new_version}; {hint}")
        done = finished_methods(where, previous)
        again = [m for m in methods if m in done]
        if again:
            raise ResultsConflict(f"{where} already holds finished results of {', '.join(again)}; {hint}")
        redo = [m for m in methods if m in (previous.get("methods") or {})]
        if redo:
            log.warning("%s: results of %s are incomplete and are run again", where, ", ".join(redo))

    def close(self) -> None:
        """Write run-level entries not yet in ``summary.json``, then release the directory lock."""
        if self._lock is not None:
            try:
                if self._pending:
                    self._write()
            finally:
                self._lock.release()
                self._lock = None

    def __enter__(self) -> ResultsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def summary(self) -> dict[str, Any]:
        """A copy of the content of ``summary.json``."""
        return copy.deepcopy(self._summary)

    @property
    def summary_path(self) -> Path:
        """Path of ``summary.json``."""
        return self.out_dir / SUMMARY_FILE

    def add_method(self, name: str, summary: dict[str, Any], steps: pd.DataFrame) -> Path:
        """Store one finished method: its per-step table, then the updated ``summary.json``.

        Args:
            name: Method key (``tpik``, ``hqp-daqp``, ``mink``, ...).
            summary: Output of :func:`compare.analysis.metrics.compute_summary` (extra keys allowed).
            steps: Per-step table.

        Returns:
            Path of the per-step table written.
        """
        steps_path = self._write_steps(name, steps)
        entry = to_jsonable(summary)
        entry["steps_file"] = steps_path.relative_to(self.out_dir).as_posix()
        entry["steps_rows"] = len(steps)
        if name in self._method_settings:
            entry["method_settings"] = to_jsonable(self._method_settings[name])
        self._summary["methods"][name] = entry
        errors = self._summary.get("errors")
        if errors and name in errors:  # a re-run succeeded
            del errors[name]
            if not errors:
                del self._summary["errors"]
        self._write()
        return steps_path

    def set_run_info(self, key: str, value: Any) -> None:
        """Store a run-level entry of ``summary.json`` beside ``methods`` (e.g. ``oracle``).

        It reaches the file with the next method's results (:meth:`add_method`, :meth:`add_error`),
        or when the writer closes: the run-level entries of a run are written together.
        """
        if key in ("methods", "errors"):
            raise ValueError(f"'{key}' is written by add_method/add_error")
        self._summary[key] = to_jsonable(value)
        self._pending = True

    def set_replay(self, scenario_toml: str) -> None:
        """Record what a replay rebuilds the scene from: ``replay.toml`` and ``summary["replay"]``.

        Args:
            scenario_toml: The concrete scenario simulated (random draws resolved), as TOML.
        """
        write_text_atomic(self.out_dir / REPLAY_FILE, scenario_toml)
        self.set_run_info("replay", {"format": REPLAY_FORMAT, "scenario_file": REPLAY_FILE})

    def add_error(self, name: str, message: str) -> None:
        """Record that method ``name`` failed, keeping every other method's results."""
        self._summary.setdefault("errors", {})[name] = str(message)
        self._write()

    def _write_steps(self, name: str, steps: pd.DataFrame) -> Path:
        steps_dir = self.out_dir / STEPS_DIR
        steps_dir.mkdir(exist_ok=True)
        stem = safe_name(name)
        parquet = steps_dir / f"{stem}.parquet"
        try:
            atomic_write(parquet, lambda tmp: write_steps_parquet(steps, tmp))
            (steps_dir / f"{stem}.csv").unlink(missing_ok=True)
            return parquet
        except Exception as exc:  # a column Parquet cannot encode: CSV always works
            log.warning("Parquet failed for %s (%s); writing CSV", name, exc)
            parquet.unlink(missing_ok=True)
            csv = steps_dir / f"{stem}.csv"
            atomic_write(csv, lambda tmp: steps.to_csv(tmp, index=False))
            return csv

    def _write(self) -> None:
        write_json_atomic(self.summary_path, to_jsonable(self._summary))
        self._pending = False


def merge_run_summary(run_dir: Path, incoming: dict[str, Any]) -> dict[str, Any]:
    """Merge a run's ``summary.json`` written elsewhere (a Ray worker) into ``run_dir``'s, atomically.

    The incoming methods and errors replace those of the same name; the others are kept. Without
    a readable summary in ``run_dir`` the incoming one is written as it is.

    Returns:
        The summary written.
    """
    try:
        merged = read_previous(run_dir)
    except ResultsConflict:
        merged = None
    if merged is None:
        merged = incoming
    else:
        for key, value in incoming.items():  # run-level entries the older summary lacks (e.g. replay)
            if key not in ("methods", "errors"):
                merged.setdefault(key, value)
        merged["methods"].update(incoming.get("methods") or {})
        errors = {k: v for k, v in (merged.get("errors") or {}).items() if k not in incoming.get("methods", {})}
        errors.update(incoming.get("errors") or {})
        merged.pop("errors", None)
        if errors:
            merged["errors"] = errors
    write_json_atomic(Path(run_dir) / SUMMARY_FILE, merged)
    return merged


def load_summary(results_dir: Path) -> dict[str, Any]:
    """Read ``results_dir/summary.json``.

    Raises:
        FileNotFoundError: No summary in ``results_dir``.
    """
    with open(Path(results_dir) / SUMMARY_FILE, encoding="utf-8") as fh:
        return json.load(fh)


def load_steps(results_dir: Path, method: str, columns: Sequence[str] | None = None) -> pd.DataFrame:
    """Read the per-step table of ``method`` (Parquet or CSV), only ``columns`` when given.

    Raises:
        FileNotFoundError: No table for ``method``; the message lists the available ones.
    """
    steps_dir = Path(results_dir) / STEPS_DIR
    stem = safe_name(method)
    parquet = steps_dir / f"{stem}.parquet"
    wanted = list(columns) if columns is not None else None
    if parquet.is_file():
        return pd.read_parquet(parquet, columns=wanted)
    csv = steps_dir / f"{stem}.csv"
    if csv.is_file():
        return pd.read_csv(csv, usecols=wanted)
    available = sorted(p.stem for p in steps_dir.glob("*") if not is_temporary(p)) if steps_dir.is_dir() else []
    raise FileNotFoundError(
        f"no per-step table for method '{method}' in {steps_dir} (available: {', '.join(available) or 'none'})"
    )


# --------------------------------------------------------------------------------------------- sweeps


def sweep_run_dir(out_dir: Path, index: int) -> Path:
    """Directory of run ``index`` of a sweep: ``out_dir/runs/00042``."""
    return Path(out_dir) / RUNS_DIR / f"{int(index):05d}"


def is_finished(run_dir: Path, methods: Iterable[str] | None = None) -> bool:
    """Whether ``run_dir`` holds complete results (:func:`finished_methods`) of every method.

    Args:
        run_dir: Run directory.
        methods: Methods that must be finished; None = at least one method and no recorded error.

    Returns:
        False if the summary is missing or unreadable, a requested method is missing or has an
        incomplete table, or (with ``methods=None``) an error is recorded — such runs are re-run
        by a resumed sweep.
    """
    try:
        summary = load_summary(run_dir)
    except (OSError, ValueError):
        return False
    done = finished_methods(run_dir, summary)
    if methods is None:
        return bool(done) and not summary.get("errors") and done == set(summary.get("methods") or {})
    return all(m in done for m in methods)


def flatten_method(summary: Mapping[str, Any]) -> dict[str, Any]:
    """Key metrics of one method summary as a flat dict (one row of ``sweep_runs.csv``).

    The columns of every registered metric (:meth:`~compare.analysis.metric.Metric.columns`).
    Missing values are ``None``; a group the scenario does not have gives ``None`` margins and
    ``0`` violations.
    """
    row: dict[str, Any] = {}
    for metric in registered_metrics():
        row.update(metric.columns(summary))
    return row


def collect_sweep(out_dir: Path) -> pd.DataFrame:
    """One row per (run, method) of a sweep: seed, key metrics, and ``error`` for failed methods.

    Runs without a readable ``summary.json`` are skipped. Columns: ``run``, ``scenario``,
    ``seed``, ``method``, ``error`` (None when the method finished) and those of
    :func:`flatten_method`.
    """
    runs_dir = Path(out_dir) / RUNS_DIR
    rows: list[dict[str, Any]] = []
    for run_dir in sorted(p for p in runs_dir.glob("*") if p.is_dir()) if runs_dir.is_dir() else []:
        try:
            summary = load_summary(run_dir)
        except (OSError, ValueError):
            continue
        base = {"run": run_dir.name, "scenario": summary.get("scenario"), "seed": summary.get("seed")}
        for method, msum in (summary.get("methods") or {}).items():
            rows.append({**base, "method": method, "error": None, **flatten_method(msum)})
        for method, message in (summary.get("errors") or {}).items():
            if method not in (summary.get("methods") or {}):
                rows.append({**base, "method": method, "error": message})
    frame = pd.DataFrame(rows)
    if frame.empty:
        return pd.DataFrame(columns=["run", "scenario", "seed", "method", "error"])
    return frame


def summarize_sweep_rows(runs: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Per-method aggregates of a :func:`collect_sweep` table (the ``methods`` of ``sweep_summary.json``).

    Per method: ``runs`` (finished), ``errors``, and the aggregates of every registered metric
    (:meth:`~compare.analysis.metric.Metric.aggregates`) over its finished runs.
    """
    if runs.empty or "method" not in runs.columns:
        return {}
    return {str(method): _method_aggregate(rows) for method, rows in runs.groupby("method", sort=False)}


def _method_aggregate(rows: pd.DataFrame) -> dict[str, Any]:
    ok = SweepRuns(rows[rows["error"].isna()] if "error" in rows.columns else rows)
    out: dict[str, Any] = {"runs": ok.n, "errors": int(len(rows) - ok.n)}
    for metric in registered_metrics():
        out.update(metric.aggregates(ok))
    return out


def run_summaries(sweep_dir: Path) -> list[dict[str, Any]]:
    """Every readable ``summary.json`` of a sweep's runs, in run order (unreadable ones left out)."""
    runs_dir = Path(sweep_dir) / RUNS_DIR
    out = []
    for run_dir in sorted(p for p in runs_dir.glob("*") if p.is_dir()) if runs_dir.is_dir() else []:
        try:
            out.append(json.loads((run_dir / SUMMARY_FILE).read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue
    return out


PAIRED_OUTCOMES: dict[str, tuple[str, ...]] = {
    "limit_or_wall_violation": ("joint_limits", "walls"),
    "obstacle_violation": ("obstacles",),
}
"""Per-run yes/no outcomes compared between methods (``"paired"`` of ``sweep_summary.json``)."""


def paired_comparisons(runs: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """Exact McNemar test per pair of methods on :data:`PAIRED_OUTCOMES`, over the seeds both finished.

    Returns:
        ``{"<a> vs <b>": {"runs": n, "<outcome>": {"a_only", "b_only", "both", "neither",
        "p_value"}, ...}}`` for every pair in the order the methods appear.
    """
    if runs.empty or "method" not in runs.columns:
        return {}
    ok = runs[runs["error"].isna()] if "error" in runs.columns else runs
    outcome_cols: dict[str, pd.DataFrame] = {}
    for outcome, groups in PAIRED_OUTCOMES.items():
        flags = np.zeros(len(ok), dtype=bool)
        for group in groups:
            col = f"{group}_violations"
            if col in ok.columns:
                flags |= pd.to_numeric(ok[col], errors="coerce").fillna(0).to_numpy() > 0
        outcome_cols[outcome] = pd.DataFrame({"seed": ok["seed"], "method": ok["method"], "flag": flags}).pivot_table(
            index="seed", columns="method", values="flag", aggfunc="max"
        )
    methods = [str(m) for m in dict.fromkeys(ok["method"])]
    out: dict[str, dict[str, Any]] = {}
    for i, a in enumerate(methods):
        for b in methods[i + 1 :]:
            entry: dict[str, Any] = {}
            for outcome, table in outcome_cols.items():
                both = table[[a, b]].dropna()
                test = mcnemar(both[a].astype(bool).to_numpy(), both[b].astype(bool).to_numpy())
                entry["runs"] = test.pop("runs")
                entry[outcome] = test
            out[f"{a} vs {b}"] = entry
    return out


TIMING_KEYS = frozenset(
    {
        "solve_time_us",
        "realtime_factor",
        "wall_time_s",
        "solve_time_us_by_active_count",
        "versions",
        "steps_file",
        "deadline_misses",
        "deadline_steal_excused",
        "solve_worst_us",
        "cpu_time_s",
        "cpu_system_s",
        "sim_s_per_cpu_s",
        "steal_time_s",
    }
)
"""Keys of ``summary.json`` whose values depend on the machine's speed or environment, not on
(config, seed): left out when runs are compared for determinism."""


TIMING_COLUMNS = ("solve_time_us", "deadline_miss")
"""Columns of a per-step table measured on the machine (the solve time and what it decides): the
rest of the table is a function of (config, seed)."""


def deterministic_view(summary: Any) -> Any:
    """``summary`` without the :data:`TIMING_KEYS` (recursively): equal for equal (config, seed)."""
    if isinstance(summary, dict):
        return {k: deterministic_view(v) for k, v in summary.items() if k not in TIMING_KEYS}
    if isinstance(summary, list):
        return [deterministic_view(v) for v in summary]
    return summary


def write_sweep_summary(out_dir: Path, runs: pd.DataFrame | None = None) -> dict[str, Any]:
    """Aggregate a sweep per method; write ``sweep_summary.json`` and ``sweep_runs.csv``.

    Args:
        out_dir: Sweep directory.
        runs: Output of :func:`collect_sweep` (collected here if None).

    Returns:
        ``{"runs": <run directories with a summary>, "scenario", "versions",
        "methods": {method: {"runs", "errors", "share_runs_limit_or_wall_violation",
        "share_runs_obstacle_violation", "share_runs_any_violation",
        "solve_time_us": {"median_of_medians", "median_of_medians_ci95", "p99_of_medians",
        "median_of_p99", "max"},
        "worst_safety_margin": {group: ...}, "worst_physical_margin": {group: ...},
        "min_obstacle_distance_m", "ee_error_final_m": {"median", "max"}, "failures",
        "fallbacks", "activation_toggles_per_s_median", "status_steps", "fallback_steps",
        "time_below_physical_s", "deadline_misses", "deadline_steal_excused", "warmup_steps", ...}},
        "paired": {"<a> vs <b>": ...}}`` (:func:`paired_comparisons`). Every share of runs is
        ``{"count", "runs", "rate", "ci95"}`` (Wilson, :func:`compare.analysis.statistics.rate`),
        over the runs where the method finished; a violation is any safety-margin episode
        (``violations > 0``). ``median_of_medians_ci95`` is a bootstrap 95 % interval.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if runs is None:
        runs = collect_sweep(out_dir)
    atomic_write(out_dir / SWEEP_RUNS_FILE, lambda tmp: runs.to_csv(tmp, index=False))
    summary: dict[str, Any] = {
        "runs": int(runs["run"].nunique()) if not runs.empty else 0,
        "scenario": None,
        "versions": run_versions(),
        "methods": {},
    }
    if not runs.empty:
        scenarios = runs["scenario"].dropna().unique()
        summary["scenario"] = str(scenarios[0]) if len(scenarios) == 1 else [str(s) for s in scenarios]
        summary["methods"] = summarize_sweep_rows(runs)
        summary["paired"] = paired_comparisons(runs)
    summary = to_jsonable(summary)
    write_json_atomic(out_dir / SWEEP_SUMMARY_FILE, summary)
    return summary
