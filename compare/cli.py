"""``tpik-compare``: run scenarios, sweeps, plots, benchmarks, replays and the viewer (docs/design.md §7).

User mistakes (bad config, unknown method, missing directory) print one line on stderr
and exit with code 2; no traceback. Every command gets that for the error roots of the
packages (:data:`USER_ERRORS`) from :class:`_App`.

Start-up: a command imports what it runs when it runs ("Deferred" imports: ``compare.config``,
``compare.run``, the campaign, analysis, replay, bench and hardware modules). Together they cost
more than a second of CPU (pandas, matplotlib, scipy.stats, rerun, pydantic models), each of them
at least ~0.1 s (``compare.config`` alone ~0.1 s, ``compare.bench.suite`` ~1 s), which ``--help``
and the commands that do not need them do not pay (the list of deferred imports: pyproject.toml,
``[tool.importlinter]``).
"""

from __future__ import annotations

import functools
import json
import logging
import os
import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from compare.analysis.exceptions import ResultsError
from compare.exceptions import CompareError
from compare.hardware.exceptions import HardwareError
from compare.methods import ablation_methods, available_methods, describe
from qp_baseline.exceptions import HqpError
from robots.exceptions import RobotError
from tpik.exceptions import TpikError

if TYPE_CHECKING:
    from compare.config import Config

USER_ERRORS: tuple[type[Exception], ...] = (CompareError, TpikError, RobotError, HqpError)
"""The error roots of the packages: what a user mistake raises (config, method, settings, files)."""

log = logging.getLogger(__name__)

_F = TypeVar("_F", bound=Callable[..., Any])


def _one_line_errors(command: _F) -> _F:
    """Run a command; a :data:`USER_ERRORS` exception becomes ``error: <message>`` and exit code 2."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except USER_ERRORS as exc:
            log.debug("%s", exc, exc_info=True)
            _fail(str(exc))

    return wrapper  # type: ignore[return-value]


class _App(typer.Typer):
    """A Typer app whose every command turns a user mistake into one line (:func:`_one_line_errors`)."""

    def command(self, *args: Any, **kwargs: Any) -> Callable[[_F], _F]:  # type: ignore[override]
        register = super().command(*args, **kwargs)

        def decorator(fn: _F) -> _F:
            register(_one_line_errors(fn))
            return fn

        return decorator


app = _App(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode=None,  # help texts are plain: "[m]" and "[scenario] robot" are units and config keys
    help="Set-based task-priority IK vs hierarchical QP vs mink on a robot arm ([scenario] robot), side by side.",
)

EXIT_USAGE = 2
EXIT_HALTED = 3
"""``tpik-compare hw``: the run was halted for a safety cause (a foreign publisher); its results are written."""

AllowNetworkOpt = Annotated[
    bool,
    typer.Option(
        "--allow-network-master",
        help="Run even if ROS_MASTER_URI names another host or the master or this node listens beyond loopback "
        "(ROS 1 cannot authenticate: a dedicated network behind a firewall only; docs/hardware.md).",
    ),
]


def _fail(message: str) -> None:
    first = message.strip().splitlines()[0] if message.strip() else "unknown error"
    typer.echo(f"error: {first}", err=True)
    raise typer.Exit(EXIT_USAGE)


def _overrides(
    duration: float | None,
    time_scale: float | None,
    sensing: str | None,
    simulation: str | None = None,
    drive: str | None = None,
    seed: int | None = None,
) -> dict[str, object]:
    out: dict[str, object] = {}
    if seed is not None:
        out["scenario.seed"] = seed
    if duration is not None:
        out["scenario.duration_s"] = duration
    if time_scale is not None:
        out["scenario.time_scale"] = time_scale
    if sensing is not None:
        out["scenario.sensing"] = sensing
    if simulation is not None:
        out["scenario.simulation"] = simulation
    if drive is not None:
        out["scenario.drive"] = drive
    return out


ConfigArg = Annotated[Path, typer.Argument(help="Scenario TOML file (see configs/).", show_default=False)]
MethodsOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--methods",
        "-m",
        help="Methods to run instead of the config's (repeatable): tpik, tpik-paper, hqp-<backend>, mink, "
        "mink-hard, ...; what each is: tpik-compare methods.",
    ),
]
SeedOpt = Annotated[
    int | None,
    typer.Option(
        "--seed",
        min=0,
        help="First seed (override scenario.seed). Report on seeds no tuning saw: 100000 (docs/benchmarks.md).",
    ),
]
WorkersOpt = Annotated[int, typer.Option("--workers", "-w", min=1, help="Parallel worker processes.")]
DurationOpt = Annotated[float | None, typer.Option("--duration", help="Override scenario.duration_s [s].")]
ScaleOpt = Annotated[
    float | None, typer.Option("--time-scale", help="Override scenario.time_scale (short form of a scenario).")
]
SensingOpt = Annotated[str | None, typer.Option("--sensing", help="Override scenario.sensing: depth | geometric.")]
SimulationOpt = Annotated[
    str | None,
    typer.Option(
        "--simulation",
        help="Override scenario.simulation: dynamic (MuJoCo physics) | kinematic (q += q̇ dt, perfect tracking).",
    ),
]
OverwriteRunOpt = Annotated[
    bool,
    typer.Option(
        "--overwrite",
        help="Discard the results already in --out (every method) and write these instead. Without it, "
        "results of the same scenario and config are kept and these methods added; anything else is refused.",
    ),
]
DriveOpt = Annotated[
    str | None,
    typer.Option(
        "--drive",
        help="Override scenario.drive of dynamic simulation: decoupled (inverse dynamics) | servo (MJCF P servos).",
    ),
]
OracleOpt = Annotated[
    bool | None,
    typer.Option(
        "--oracle/--no-oracle",
        help="Override oracle.enabled: the clairvoyant reference that splits obstacle violations into"
        " avoidable / unavoidable.",
    ),
]


SetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override any config key (repeatable): KEY=VALUE with a dotted key and a TOML value, e.g."
        " --set sensor.rho_m=1.0 --set prediction.horizon_s=0.25.",
    ),
]
PredictionOpt = Annotated[
    str | None,
    typer.Option(
        "--prediction",
        help="Override prediction.mode: off | estimated (the person's motion from the sensing stream, fed to every"
        " method's obstacle tasks) | truth (the person's true future: the bound).",
    ),
]


def _select_methods(cfg: Config, methods: list[str] | None) -> Config:
    """``cfg`` with only ``methods`` (and their settings) when given; raises ConfigError."""
    if not methods:
        return cfg
    # Deferred: start-up cost (module docstring).
    from compare.config import parse_config

    data = cfg.model_dump(mode="python")
    data["methods"] = {
        "names": list(methods),
        "settings": {k: v for k, v in cfg.methods.settings.items() if k in methods},
    }
    return parse_config(data)


def _with_options(
    overrides: dict[str, object], oracle: bool | None, prediction: str | None = None, sets: list[str] | None = None
) -> dict[str, object]:
    """``overrides`` with --oracle, --prediction and every --set KEY=VALUE (a bad one: exit 2)."""
    # Deferred: start-up cost (module docstring).
    from compare.config import override_value

    if oracle is not None:
        overrides["oracle.enabled"] = oracle
    if prediction is not None:
        overrides["prediction.mode"] = prediction
    for item in sets or []:
        key, sep, text = item.partition("=")
        if not sep or not key.strip() or not text.strip():
            _fail(f"--set: KEY=VALUE expected, got '{item}'")
        overrides[key.strip()] = override_value(text)
    return overrides


@app.command()
def run(
    config: ConfigArg,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Results directory [results/<scenario>].")] = None,
    methods: MethodsOpt = None,
    duration: DurationOpt = None,
    time_scale: ScaleOpt = None,
    sensing: SensingOpt = None,
    simulation: SimulationOpt = None,
    drive: DriveOpt = None,
    plots: Annotated[bool, typer.Option(help="Write the plots after the run.")] = True,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    overwrite: OverwriteRunOpt = False,
    oracle: OracleOpt = None,
    prediction: PredictionOpt = None,
    sets: SetOpt = None,
    seed: Annotated[
        int | None, typer.Option("--seed", min=0, help="Override scenario.seed (a random family's draw).")
    ] = None,
) -> None:
    """Run one scenario with every selected method; write summary.json, per-step tables, plots, report.md.

    An --out that already holds results of the same scenario and config gets these methods added
    (the others' results are kept); a different config, or a method it already has finished
    results of, is refused (exit 2) unless --overwrite.
    """
    # Deferred: start-up cost (module docstring).
    from compare.campaign.realize import realize_with_verdict
    from compare.config import ConfigError, load_config
    from compare.run import run_scenario

    overrides = _with_options(
        _overrides(duration, time_scale, sensing, simulation, drive, seed), oracle, prediction, sets
    )
    try:
        cfg, text = load_config(config, overrides)
        cfg = _select_methods(cfg, methods)
    except ConfigError as exc:
        _fail(str(exc))
        return
    out_dir = out or Path("results") / cfg.scenario.name
    try:
        summary = run_scenario(
            cfg,
            out_dir,
            config_text=text,
            progress=not quiet,
            make_plots=plots,
            overwrite=overwrite,
            prepare=realize_with_verdict,
        )
    except ResultsError as exc:
        _fail(str(exc))
        return
    _print_summary(summary, out_dir)
    if summary.get("errors"):
        raise typer.Exit(1)


def _print_summary(summary: dict[str, object], out_dir: Path) -> None:
    # Deferred: start-up cost (module docstring).
    from compare.analysis.report import summary_table

    console = Console()
    if not console.is_terminal:
        console = Console(width=160)  # a log or a pipe: one line per method
    console.print(summary_table(summary, narrow=console.width < 140))
    console.print(f"results: {out_dir}/summary.json   plots: {out_dir}/plots/")
    console.print(f"report:  {out_dir}/report.md")


@app.command()
def sweep(
    config: ConfigArg,
    n: Annotated[int, typer.Option("--n", "-n", min=1, help="Number of randomized runs (seeds seed..seed+n-1).")] = 10,
    workers: WorkersOpt = 2,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Sweep directory [results/sweep-<scenario>].")] = None,
    methods: MethodsOpt = None,
    seed: SeedOpt = None,
    duration: DurationOpt = None,
    time_scale: ScaleOpt = None,
    sensing: Annotated[
        str | None, typer.Option("--sensing", help="depth | geometric (sweeps default to geometric).")
    ] = None,
    simulation: SimulationOpt = None,
    drive: DriveOpt = None,
    executor: Annotated[
        str, typer.Option("--executor", help="local (worker processes) | ray (a Ray cluster, extra 'cluster').")
    ] = "local",
    address: Annotated[
        str | None,
        typer.Option("--address", help="Ray cluster to join (auto, ray://host:10001); default: a local Ray instance."),
    ] = None,
    overwrite: Annotated[
        bool,
        typer.Option(
            "--overwrite",
            help="Discard the sweep already in --out and start again. Without it, a re-run resumes: finished "
            "(run, method) pairs are kept, missing ones run; another config, plant, seed or version is refused.",
        ),
    ] = False,
    oracle: OracleOpt = None,
    prediction: PredictionOpt = None,
    sets: SetOpt = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Run a randomized batch in parallel; re-running the same command resumes it.

    The sweep directory records its config, plant, seeds, methods and project version
    (sweep_manifest.json). A re-run keeps every finished (run, method) pair and runs the missing
    ones: more --n or other -m methods extend the sweep. A different config, plant, first seed,
    method settings or project version is refused (exit 2) unless --overwrite.
    """
    # Deferred: start-up cost (module docstring).
    from compare.campaign.sweep import run_sweep
    from compare.config import ConfigError, load_config

    overrides = _overrides(duration, time_scale, sensing or "geometric", simulation, drive, seed)
    try:
        cfg, text = load_config(config, _with_options(overrides, oracle, prediction, sets))
    except ConfigError as exc:
        _fail(str(exc))
        return
    out_dir = out or Path("results") / f"sweep-{cfg.scenario.name}"
    try:
        summary = run_sweep(
            cfg,
            text,
            out_dir,
            n=n,
            workers=workers,
            methods=list(methods) if methods else None,
            executor=executor,
            address=address,
            progress=not quiet,
            overwrite=overwrite,
        )
    except (ConfigError, ResultsError) as exc:
        _fail(str(exc))
        return
    typer.echo(f"sweep summary: {out_dir}/sweep_summary.json ({summary.get('runs', n)} runs)")
    typer.echo(f"sweep report:  {out_dir}/sweep_report.md")


@app.command("critical-speed")
def critical_speed(
    config: ConfigArg,
    out: Annotated[Path, typer.Option("--out", "-o", help="Output directory (critical_speed.json, plot, runs/).")],
    methods: MethodsOpt = None,
    speeds: Annotated[
        str | None,
        typer.Option(
            "--speeds", help="Torso approach speeds [m/s], comma-separated (default: 12 log-spaced in 0.1-1.6)."
        ),
    ] = None,
    seeds: Annotated[int, typer.Option("--seeds", min=1, help="Directions per speed (seed 0: the case's own).")] = 3,
    spread_deg: Annotated[float, typer.Option("--spread-deg", help="Largest turn of the person's path [deg].")] = 20.0,
    shift_s: Annotated[float, typer.Option("--shift-s", help="Largest time shift of the person's motion [s].")] = 2.0,
    workers: Annotated[int, typer.Option("--workers", "-w", min=1, help="Parallel worker processes.")] = 1,
    duration: DurationOpt = None,
    time_scale: ScaleOpt = None,
    sensing: Annotated[
        str | None, typer.Option("--sensing", help="depth | geometric (default geometric, as sweeps).")
    ] = None,
    simulation: SimulationOpt = None,
    drive: DriveOpt = None,
    oracle: OracleOpt = None,
    prediction: PredictionOpt = None,
    sets: SetOpt = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Sweep the person's approach speed on a case's geometry: each method's critical speed."""
    # Deferred: start-up cost (module docstring).
    from compare.campaign.critical_speed import run_critical_speed
    from compare.config import ConfigError, load_config

    overrides = _with_options(
        _overrides(duration, time_scale, sensing or "geometric", simulation, drive), oracle, prediction, sets
    )
    try:
        values = None if speeds is None else [float(v) for v in speeds.split(",") if v.strip()]
    except ValueError:
        _fail(f"--speeds: comma-separated numbers expected, got '{speeds}'")
        return
    try:
        cfg = _select_methods(load_config(config, overrides)[0], methods)
        result = run_critical_speed(cfg, out, values, seeds, spread_deg, shift_s, workers=workers, progress=not quiet)
    except ConfigError as exc:
        _fail(str(exc))
        return
    for name, entry in result.items():
        typer.echo(
            f"{name}: critical approach speed safety {entry['safety_mps']} m/s, physical {entry['physical_mps']} m/s"
        )
    typer.echo(f"results: {out}/critical_speed.json   plot: {out}/critical_speed.png")


@app.command()
def claims(
    results: Annotated[
        list[Path], typer.Argument(help="Run directories (summary.json) and/or critical-speed directories.")
    ],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Write the table (Markdown) and a .json.")] = None,
    label: Annotated[
        list[str] | None, typer.Option("--label", help="Column label per RESULTS entry (default: derived).")
    ] = None,
) -> None:
    """The paper's claims of Sec. IV measured per method: one table for runs and critical speeds."""
    # Deferred: start-up cost (module docstring).
    from compare.analysis.claims import claims_report

    try:
        text, data = claims_report(results, label)
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc))
        return
    typer.echo(text)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n", encoding="utf-8")
        out.with_suffix(".json").write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


@app.command("paper-claims")
def paper_claims(
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Run directories and the tables (claims.md, claims.json).")
    ] = Path("results/paper-claims"),
    seeds: Annotated[
        list[int] | None, typer.Option("--seed", help="Scenario seed (repeatable; default 0).", show_default=False)
    ] = None,
    methods: MethodsOpt = None,
    configs: Annotated[Path, typer.Option(help="Folder of the case configs.")] = Path("configs"),
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars.")] = False,
    prediction: PredictionOpt = None,
    sets: SetOpt = None,
) -> None:
    """Run the paper's case studies (and their paper-paced variants) and print the claims of Sec. IV per method.

    The same tables as README.md's, regenerated on this code (compare/campaign/paper_claims.py);
    runs already in --out with the same config are reused. --prediction and --set apply to every case.
    """
    # Deferred: start-up cost (module docstring).
    from compare.campaign.paper_claims import CASES, claims_details, claims_json, claims_tables, run_paper_claims
    from compare.config import ConfigError

    missing = [name for name, _ in CASES if not (configs / name).is_file()]
    if missing:
        _fail(f"{configs}: missing case configs {', '.join(missing)}")
        return
    picked = seeds or [0]
    try:
        results = run_paper_claims(
            configs,
            out,
            picked,
            methods,
            progress=not quiet,
            announce=typer.echo,
            overrides=_with_options({}, None, prediction, sets),
        )
    except (ConfigError, ResultsError) as exc:
        _fail(str(exc))
        return
    tables = claims_tables(results, picked)
    out.mkdir(parents=True, exist_ok=True)
    (out / "claims.md").write_text(tables + "\n\n" + claims_details(results) + "\n", encoding="utf-8")
    (out / "claims.json").write_text(json.dumps(claims_json(results), indent=2) + "\n", encoding="utf-8")
    typer.echo(tables)
    typer.echo(f"tables and what was measured: {out / 'claims.md'}")


@app.command()
def ablation(
    config: ConfigArg,
    n: Annotated[int, typer.Option("--n", "-n", min=1, help="Number of randomized runs (seeds seed..seed+n-1).")] = 10,
    workers: WorkersOpt = 2,
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="Sweep directory [results/ablation-<scenario>].")
    ] = None,
    seed: SeedOpt = None,
    duration: DurationOpt = None,
    simulation: SimulationOpt = None,
    drive: DriveOpt = None,
) -> None:
    """TPIK ablation: tpik, tpik-paper and each deviation of tpik switched off alone, on the same seeds.

    A resumable sweep of those methods (geometric sensing), then ablation.md / ablation.json:
    violations (Wilson 95 %, McNemar p vs tpik), toggles/s, EE error, solve time.
    """
    # Deferred: start-up cost (module docstring).
    from compare.campaign.ablation import write_ablation
    from compare.campaign.sweep import run_sweep
    from compare.config import ConfigError, load_config

    try:
        cfg, text = load_config(config, _overrides(duration, None, "geometric", simulation, drive, seed))
    except ConfigError as exc:
        _fail(str(exc))
        return
    out_dir = out or Path("results") / f"ablation-{cfg.scenario.name}"
    try:
        run_sweep(cfg, text, out_dir, n=n, workers=workers, methods=ablation_methods())
    except ConfigError as exc:
        _fail(str(exc))
        return
    report = write_ablation(out_dir)
    typer.echo(f"ablation table: {report}")
    typer.echo(f"sweep report:   {out_dir}/sweep_report.md")


@app.command()
def tune(
    config: ConfigArg,
    method: Annotated[str, typer.Option("--method", "-m", help="The method whose settings are tuned.")],
    grid: Annotated[
        list[str],
        typer.Option(
            "--grid",
            help="A setting of [methods.settings.METHOD] and its values (repeatable): KEY=V1,V2,... "
            "Every combination is one sweep.",
        ),
    ],
    n: Annotated[int, typer.Option("--n", "-n", min=1, help="Number of randomized runs (seeds seed..seed+n-1).")] = 10,
    workers: WorkersOpt = 2,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Grid directory [results/tune-<method>].")] = None,
    seed: SeedOpt = None,
    duration: DurationOpt = None,
) -> None:
    """Tune a method's settings on a grid: one resumable sweep per grid point, then tuning.md / tuning.json.

    Each point runs the method alone on the same seeds (geometric sensing) in OUT/<point>/; the
    points are ranked by joint-limit/wall violations, time below a physical threshold, failed
    steps, then the final EE error (compare/campaign/tuning.py). Tune on seeds 0-999, report on
    100000+ (docs/benchmarks.md, "Equal care").
    """
    # Deferred: start-up cost (module docstring).
    from compare.campaign.sweep import run_sweep
    from compare.campaign.tuning import grid_points, parse_grid, point_name, point_overrides, write_tuning
    from compare.config import ConfigError, load_config

    points = grid_points(parse_grid(grid))
    out_dir = out or Path("results") / f"tune-{method}"
    base = _overrides(duration, None, "geometric", None, None, seed)
    loaded = []
    try:  # every point's settings checked before the first run
        loaded = [load_config(config, {**base, **point_overrides(method, point)}) for point in points]
    except ConfigError as exc:
        _fail(str(exc))
    for point, (cfg, text) in zip(points, loaded, strict=True):
        typer.echo(f"grid point {point_name(point)}")
        try:
            run_sweep(cfg, text, out_dir / point_name(point), n=n, workers=workers, methods=[method])
        except (ConfigError, ResultsError) as exc:
            _fail(str(exc))
    words = ["tpik-compare", "tune", str(config), "-m", method, *(w for g in grid for w in ("--grid", g))]
    words += ["--n", str(n), "--workers", str(workers), "--out", str(out_dir)]
    words += [] if seed is None else ["--seed", str(seed)]
    words += [] if duration is None else ["--duration", str(duration)]
    report = write_tuning(out_dir, method, points, shlex.join(words))
    typer.echo(f"tuning table: {report}")


@app.command()
def plot(results: Annotated[Path, typer.Argument(help="A run or sweep results directory.")]) -> None:
    """Draw the plots of a finished run (summary.json; its report.md then links them) or sweep (runs/)."""
    # Deferred: start-up cost (module docstring).
    from compare.analysis.plots import plot_campaign, plot_run, plot_sweep
    from compare.analysis.run_report import render_run_report

    if (results / "summary.json").is_file():
        paths = plot_run(results)
        render_run_report(results)
    elif (results / "runs").is_dir():
        paths = plot_sweep(results) + plot_campaign(results)
    else:
        _fail(f"{results}: neither a run (summary.json) nor a sweep (runs/) directory")
        return
    for p in paths:
        typer.echo(str(p))


@app.command("methods")
def list_methods() -> None:
    """Every method name this installation accepts (-m, [methods] names), with what it is."""
    names = available_methods()
    width = max(len(n) for n in names)
    for name in names:
        typer.echo(f"{name:<{width}}  {describe(name)}")


def _parse_size(size: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` [px] as two integers; a malformed value exits with one line."""
    parts = size.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        _fail(f"--size must be WIDTHxHEIGHT in pixels (e.g. 1280x720), got '{size}'")
    return int(parts[0]), int(parts[1])


@app.command()
def replay(
    results: Annotated[Path, typer.Argument(help="A run directory, or a sweep directory with --seed.")],
    methods: Annotated[
        list[str] | None,
        typer.Option("--method", "-m", help="Method to show (repeatable; default every method of the run)."),
    ] = None,
    seed: Annotated[int | None, typer.Option("--seed", min=0, help="The sweep's run of this scenario seed.")] = None,
    video: Annotated[
        Path | None, typer.Option("--video", help="Write the methods side by side as an H.264 video (.mp4).")
    ] = None,
    rerun_file: Annotated[
        Path | None, typer.Option("--rerun", help="Write a 3D recording for the rerun viewer (.rrd).")
    ] = None,
    still: Annotated[Path | None, typer.Option("--still", help="Write the frame at --from as an image (.png).")] = None,
    fps: Annotated[float, typer.Option("--fps", help="Video frame rate, frames per second.")] = 25.0,
    size: Annotated[str, typer.Option("--size", help="Video and still size WIDTHxHEIGHT in pixels.")] = "1280x720",
    t_from: Annotated[
        float | None, typer.Option("--from", help="Start of the replayed window, in seconds of the run.")
    ] = None,
    t_to: Annotated[
        float | None, typer.Option("--to", help="End of the replayed window, in seconds of the run.")
    ] = None,
    depth_stride: Annotated[
        int, typer.Option("--depth-stride", min=1, help="Recording: keep every N-th depth pixel row and column.")
    ] = 4,
    workers: Annotated[
        int, typer.Option("--workers", "-w", min=1, help="Video: processes rendering segments in parallel.")
    ] = 2,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Replay a finished run: the methods side by side as a video, a 3D recording (rerun) or a still.

    The arm is redrawn from each method's recorded joint angles and the person from the run's
    scenario at the same instant (offscreen, headless); nothing is simulated again. Results
    written before runs recorded their scenario for replays are refused (exit 2).
    """
    # Deferred: start-up cost (module docstring).
    from compare.replay.panels import check_still_path, write_still
    from compare.replay.recording import check_recording_path, write_recording
    from compare.replay.run_data import load_run
    from compare.replay.video import VideoSettings, check_video_path, write_video

    if video is None and rerun_file is None and still is None:
        _fail("nothing to write: give --video FILE.mp4, --rerun FILE.rrd and/or --still FILE.png")
    for path, check in ((video, check_video_path), (rerun_file, check_recording_path), (still, check_still_path)):
        if path is not None:
            check(path)
    width, height = _parse_size(size)
    settings = VideoSettings(width, height, fps)
    run = load_run(results, methods, seed, t_from, t_to)
    names = ", ".join(m.name for m in run.methods)
    typer.echo(f"replaying {run.run_dir} ({names}; {run.t_from:g}–{run.t_to:g} s)")
    if video is not None:
        bar = Progress(TextColumn("[bold]video"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), disable=quiet)
        with bar:
            task = bar.add_task("video", total=len(settings.frame_times(run.t_from, run.t_to)))
            stats = write_video(run, video, settings, lambda done, _total: bar.update(task, completed=done), workers)
        typer.echo(
            f"video:     {video} ({stats.frames} frames, {width}x{height} at {fps:g} frames/s; "
            f"{stats.video_s:.1f} s rendered in {stats.wall_s:.1f} s by {stats.workers} process(es), "
            f"{stats.realtime_factor:.1f}x real time)"
        )
    if still is not None:
        write_still(run, still, run.t_from, width, height)
        typer.echo(f"still:     {still} (t = {run.t_from:g} s)")
    if rerun_file is not None:
        bar = Progress(TextColumn("[bold]recording {task.description}"), TimeElapsedColumn(), disable=quiet)
        with bar:
            task = bar.add_task("", total=None)
            write_recording(run, rerun_file, lambda part: bar.update(task, description=part), depth_stride)
        typer.echo(f"recording: {rerun_file} (open with: rerun {rerun_file})")


@app.command()
def bench(
    json_out: Annotated[Path | None, typer.Option("--json", help="Write results as JSON (docs/design.md §7).")] = None,
    repeats: Annotated[int, typer.Option(min=10, help="Timed calls per case.")] = 300,
    only: Annotated[str | None, typer.Option(help="solvers | sensing | correctness (default all).")] = None,
    methods: Annotated[
        list[str] | None,
        typer.Option(
            "--methods",
            "-m",
            help="Solvers: a method of the case-2 table "
            "(repeatable; default tpik tpik-paper tpik-ss hqp-daqp mink mink-posture).",
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option("--config", help="Scenario TOML: its robot, levels (case-2 hierarchy) and method settings."),
    ] = None,
    max_candidates: Annotated[
        int, typer.Option(min=-1, max=12, help="Solvers: largest |C| of the TPIK-vs-candidates table; -1 skips it.")
    ] = 8,
    rounds: Annotated[int, typer.Option(min=1, help="Correctness: timed passes over the reference states.")] = 3,
    tolerance: Annotated[
        float, typer.Option(min=1e-12, help="Correctness: level error within which a level matches the reference.")
    ] = 1e-5,
    plot_out: Annotated[
        Path | None, typer.Option("--plot", help="Correctness: write the time-vs-correctness figure.")
    ] = None,
    csv_out: Annotated[
        Path | None,
        typer.Option(
            "--csv",
            help=(
                "Correctness: one row per (state, backend): the residuals as qpbenchmark names them and both verdicts."
            ),
        ),
    ] = None,
    export_qps: Annotated[
        Path | None,
        typer.Option("--export-qps", help="Write the level QPs of the reference states as a qpbenchmark test set."),
    ] = None,
    export_method: Annotated[str, typer.Option(help="HQP method posing the exported QPs.")] = "hqp-piqp",
    backends: Annotated[
        list[str] | None,
        typer.Option("--backends", help="Correctness: HQP methods to judge (repeatable; default all six)."),
    ] = None,
) -> None:
    """Solver, sensing and QP-correctness benchmarks: medians, p95, ratios, timing vs correctness.

    --only correctness judges every HQP backend against the stored lexicographic reference
    (compare/bench/data/qp_reference.json): success rate, level errors, qpbenchmark residuals, time.
    """
    # Deferred: start-up cost (module docstring).
    from compare.bench.suite import BenchOptions, run_bench

    given = {"methods": methods, "backends": backends}
    lists: dict[str, Any] = {name: tuple(value) for name, value in given.items() if value}  # absent: the default
    options = BenchOptions(
        only=only,
        repeats=repeats,
        json_out=json_out,
        config=config,
        max_candidates=max_candidates,
        rounds=rounds,
        tolerance=tolerance,
        plot=plot_out,
        csv=csv_out,
        export_qps=export_qps,
        export_method=export_method,
        **lists,
    )
    run_bench(options)


@app.command()
def view(config: ConfigArg, method: Annotated[str, typer.Option(help="Method driving the arm.")] = "tpik") -> None:
    """Watch a scenario in the interactive MuJoCo viewer (needs a display)."""
    # Deferred: start-up cost (module docstring).
    from compare.config import ConfigError, load_config

    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        _fail("no display found (DISPLAY is not set): use `tpik-compare run` for headless runs")
        return
    try:
        cfg, _ = load_config(config)
    except ConfigError as exc:
        _fail(str(exc))
        return
    # Deferred: start-up cost (module docstring).
    from compare.run import view_scenario

    view_scenario(cfg, method)


@app.command()
def hw(
    config: ConfigArg,
    method: Annotated[str, typer.Option("--method", "-m", help="Method driving the arm.")] = "tpik",
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Run everything (ROS, sensing, solver, logs) but publish nothing.")
    ] = False,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Run time on the arm [s] (default: duration_s × time_scale).")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Results directory [results/hw-<scenario>].")] = None,
    time_scale: ScaleOpt = None,
    plots: Annotated[bool, typer.Option(help="Write the plots after the run.")] = True,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
    capture_background: Annotated[
        Path | None,
        typer.Option(
            "--capture-background",
            help="Only record the static background for --duration s (default 10) into this .npz; publishes nothing.",
        ),
    ] = None,
    replay: Annotated[
        Path | None,
        typer.Option(
            "--replay",
            help="Run on a recorded bag (or a directory of bags) of joint states and depth instead of the arm; "
            "publishes nothing.",
        ),
    ] = None,
    overwrite: OverwriteRunOpt = False,
    allow_network_master: AllowNetworkOpt = False,
) -> None:
    """Drive the real Jaco² and depth camera through the Kinova ROS 1 driver (docs/hardware.md).

    Exit codes: 0 done, 2 refused start (one line), 3 halted for a safety cause (a foreign
    publisher; results written), 130 interrupted.
    """
    # Deferred: start-up cost (module docstring).
    from compare.config import ConfigError, load_config

    try:
        cfg, text = load_config(config, _overrides(None, time_scale, None))
    except ConfigError as exc:
        _fail(str(exc))
        return
    if method not in cfg.methods.names:
        # Deferred: start-up cost (module docstring).
        from compare.config import parse_config

        data = cfg.model_dump(mode="python")
        settings = {k: v for k, v in cfg.methods.settings.items() if k == method}
        data["methods"] = {"names": [method], "settings": settings}
        try:
            cfg = parse_config(data)
        except ConfigError as exc:
            _fail(str(exc))
            return
    if allow_network_master:
        cfg = _allow_network(cfg)
    logging.getLogger("compare.hardware").setLevel(logging.INFO)
    if capture_background is not None:
        # Deferred: start-up cost (module docstring).
        from compare.hardware.run import capture_background_file

        try:
            covered = capture_background_file(cfg, capture_background, duration if duration is not None else 10.0)
        except HardwareError as exc:
            _fail(str(exc))
            return
        typer.echo(f"background: {capture_background} ({100.0 * covered:.0f}% of the pixels)")
        return
    out_dir = out or Path("results") / f"hw-{cfg.scenario.name}"
    # Deferred: start-up cost (module docstring).
    from compare.hardware.run import run_hardware

    total = duration if duration is not None else cfg.scenario.sim_time_s
    bar = Progress(
        TextColumn(f"[bold]{method}"),
        BarColumn(),
        TextColumn("{task.completed:5.1f}/{task.total:.0f} s"),
        TimeElapsedColumn(),
        disable=quiet,
    )
    try:
        with bar:
            task_id = bar.add_task(method, total=total)
            summary = run_hardware(
                cfg,
                method,
                out_dir,
                config_text=text,
                dry_run=dry_run,
                duration_s=duration,
                make_plots=plots,
                progress=lambda t: bar.update(task_id, completed=t),
                replay=replay,
                overwrite=overwrite,
            )
    except (HardwareError, ResultsError) as exc:
        _fail(str(exc))
        return
    except KeyboardInterrupt:
        typer.echo("interrupted: zero velocity sent", err=True)
        raise typer.Exit(130) from None
    _print_summary(summary, out_dir)
    hw_report = summary["methods"][method].get("hardware", {})
    rates = hw_report.get("rates", {})
    typer.echo(
        "measured rates [Hz]: "
        + ", ".join(f"{k} {v['rate_hz']:.1f}" for k, v in rates.items() if v.get("rate_hz") is not None)
    )
    for event in hw_report.get("watchdog_events", []):
        typer.echo(event["message"])
    if summary["methods"][method].get("interrupted"):
        raise typer.Exit(130)
    if hw_report.get("halt_cause"):
        typer.echo(f"halted: {hw_report['halt_cause']} (results in {out_dir})", err=True)
        raise typer.Exit(EXIT_HALTED)


def _allow_network(cfg: Config) -> Config:
    """``cfg`` with ``hardware.allow_network_master`` set."""
    return cfg.model_copy(update={"hardware": cfg.hardware.model_copy(update={"allow_network_master": True})})


@app.command("hw-check")
def hw_check(
    config: ConfigArg,
    frames: Annotated[int, typer.Option("--frames", min=1, max=100, help="Depth frames to compare (median).")] = 5,
    replay: Annotated[
        Path | None, typer.Option("--replay", help="Check on a recorded bag (or directory of bags) instead.")
    ] = None,
    allow_network_master: AllowNetworkOpt = False,
) -> None:
    """Check the camera calibration: render the arm model into the live depth from the configured pose."""
    # Deferred: start-up cost (module docstring).
    from compare.config import ConfigError, load_config
    from compare.hardware.run import calibration_problem, check_camera

    try:
        cfg, _ = load_config(config)
    except ConfigError as exc:
        _fail(str(exc))
        return
    if allow_network_master:
        cfg = _allow_network(cfg)
    logging.getLogger("compare.hardware").setLevel(logging.INFO)
    try:
        residual = check_camera(cfg, replay=replay, frames=frames)
    except HardwareError as exc:
        _fail(str(exc))
        return
    typer.echo(f"camera: {residual.describe()}")
    limit = cfg.hardware.calibration_max_residual_m
    problem = calibration_problem(residual, limit if limit > 0 else 0.02)
    if problem is not None:
        _fail(problem)
        return
    typer.echo(f"calibration OK (limit {100 * (limit if limit > 0 else 0.02):.1f} cm)")


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    app(args=argv if argv is not None else sys.argv[1:], prog_name="tpik-compare")


if __name__ == "__main__":
    main()
