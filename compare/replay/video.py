"""A replayed run as an H.264 video: frames of :mod:`compare.replay.panels`, encoded by ffmpeg.

Frames go through a pipe to the ffmpeg binary shipped by ``imageio-ffmpeg``, which encodes in its
own process while the next frame renders. A long video is cut into contiguous segments rendered
in parallel (this process and spawned workers, as many in all as asked for), then joined
without re-encoding.
"""

from __future__ import annotations

import multiprocessing
import queue as queue_module
import subprocess
import tempfile
import time
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from compare.replay.exceptions import ReplayError
from compare.replay.panels import PanelRenderer
from compare.replay.run_data import ReplayRun, load_run

ENCODER_PRESET = "veryfast"
"""libx264 preset: a quarter of ultrafast's file size for ~3 ms more encoder CPU a 720p frame."""
MIN_FRAMES_PER_WORKER = 100
"""A worker process costs ~2 s to start: shorter videos are rendered in this process."""


@dataclass(frozen=True)
class VideoSettings:
    """Frame size [px] (even numbers, for H.264's 4:2:0 chroma) and rate [frames/s]."""

    width: int = 1280
    height: int = 720
    fps: float = 25.0

    def __post_init__(self) -> None:
        if self.width < 64 or self.height < 64 or self.width % 2 or self.height % 2:
            raise ReplayError(f"video size must be even and at least 64x64 px, got {self.width}x{self.height}")
        if not 0.0 < self.fps <= 240.0:
            raise ReplayError(f"--fps must be in (0, 240], got {self.fps:g}")

    def frame_times(self, t_from: float, t_to: float) -> np.ndarray:
        """Instants of the frames [s]: ``t_from + k / fps``, round((t_to − t_from)·fps) of them (at least one)."""
        n = max(1, round((t_to - t_from) * self.fps))
        return t_from + np.arange(n) / self.fps


@dataclass(frozen=True)
class VideoStats:
    """What :func:`write_video` wrote: frames, video length [s], wall time of render and encoding [s], workers."""

    frames: int
    video_s: float
    wall_s: float
    workers: int = 1

    @property
    def realtime_factor(self) -> float:
        """Video seconds made per wall-clock second."""
        return self.video_s / self.wall_s if self.wall_s > 0 else float("inf")


def check_video_path(path: Path) -> Path:
    """``path`` if it names an ``.mp4`` file; raises :class:`ReplayError` otherwise."""
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise ReplayError(f"--video writes an H.264 MP4: give a .mp4 file, got {path}")
    return path


def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary imageio-ffmpeg uses; raises :class:`ReplayError` when there is none."""
    try:
        return str(imageio_ffmpeg.get_ffmpeg_exe())
    except RuntimeError as exc:
        raise ReplayError(f"no ffmpeg found for the video ({exc}); reinstall imageio-ffmpeg") from None


def _encoder(path: Path, settings: VideoSettings) -> Generator[None, np.ndarray | None, None]:
    """A started ffmpeg writer: ``send`` it frames (rows bottom-up), ``close`` it to finish the file."""
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (settings.width, settings.height),
        fps=settings.fps,
        codec="libx264",
        quality=None,
        macro_block_size=1,  # sizes are even; nothing rescaled
        ffmpeg_log_level="error",
        output_params=[
            *("-vf", "vflip", "-preset", ENCODER_PRESET, "-crf", "23", "-movflags", "+faststart"),
            *("-threads", "2"),  # x264's default (1.5 x cores) costs a fifth more CPU for the same file
        ],
    )
    writer.send(None)
    return writer


def write_video(
    run: ReplayRun,
    path: Path,
    settings: VideoSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
    workers: int = 2,
) -> VideoStats:
    """Render the run's window into an H.264 MP4 at ``path``.

    Args:
        run: The loaded run.
        path: Output file (``.mp4``; parent directories are created).
        settings: Frame size and rate (default 1280x720 at 25 frames/s).
        progress: Called as ``progress(done, total)`` as frames are done.
        workers: Processes rendering segments in parallel (fewer for a short video).

    Raises:
        ReplayError: Not an ``.mp4`` path, no ffmpeg, or rendering or ffmpeg failed.
    """
    settings = settings or VideoSettings()
    path = check_video_path(path)
    ffmpeg_exe()
    path.parent.mkdir(parents=True, exist_ok=True)
    times = settings.frame_times(run.t_from, run.t_to)
    segments = np.array_split(times, max(1, min(int(workers), len(times) // MIN_FRAMES_PER_WORKER)))
    report = progress or (lambda _done, _total: None)
    t0 = time.perf_counter()
    if len(segments) == 1:
        _write_segment(run, path, settings, times, lambda done: report(done, len(times)))
    else:
        _write_in_parallel(run, path, settings, segments, report)
    return VideoStats(len(times), len(times) / settings.fps, time.perf_counter() - t0, len(segments))


def _write_segment(
    run: ReplayRun, path: Path, settings: VideoSettings, times: np.ndarray, done: Callable[[int], None]
) -> None:
    """Render the frames at ``times`` [s] into ``path``; ``done(k)`` after the k-th."""
    with PanelRenderer(run, settings.width, settings.height) as renderer:
        writer = _encoder(path, settings)
        try:
            for k, t in enumerate(times):
                writer.send(renderer.render(float(t)))
                done(k + 1)
            writer.close()
        except (OSError, RuntimeError) as exc:
            raise ReplayError(f"ffmpeg failed writing {path}: {exc}") from None


def _segment_worker(
    run_dir: Path,
    methods: Sequence[str],
    window: tuple[float, float],
    path: Path,
    settings: VideoSettings,
    times: np.ndarray,
    messages: multiprocessing.Queue,
) -> None:
    """Worker process: load the run, render one segment; report ``("frame", 1)``, then ``("done", error)``."""
    try:
        run = load_run(run_dir, methods, None, *window)
        _write_segment(run, path, settings, times, lambda _k: messages.put(("frame", 1)))
    except Exception as exc:  # every failure goes back to the parent, which raises it as one line
        messages.put(("done", f"{type(exc).__name__}: {exc}"))
    else:
        messages.put(("done", None))


def _write_in_parallel(
    run: ReplayRun,
    path: Path,
    settings: VideoSettings,
    segments: Sequence[np.ndarray],
    report: Callable[[int, int], None],
) -> None:
    """The first segment rendered here, each other by a spawned process (no GL state inherited); then joined."""
    ctx = multiprocessing.get_context("spawn")
    messages: multiprocessing.Queue = ctx.Queue()
    total = sum(len(s) for s in segments)
    counter = _FrameCounter(messages, lambda done: report(done, total))
    window = (run.t_from, run.t_to)
    methods = [m.name for m in run.methods]
    with tempfile.TemporaryDirectory(prefix=".replay-", dir=path.parent) as tmp:
        parts = [Path(tmp) / f"part{i:02d}.mp4" for i in range(len(segments))]
        procs = [
            ctx.Process(
                target=_segment_worker, args=(run.run_dir, methods, window, p, settings, s, messages), daemon=True
            )
            for p, s in zip(parts[1:], segments[1:], strict=True)
        ]
        for proc in procs:
            proc.start()
        try:
            _write_segment(run, parts[0], settings, segments[0], lambda _k: counter.add_local_frame())
            errors = counter.wait(procs)
        finally:
            for proc in procs:
                proc.join(timeout=5.0)
                if proc.is_alive():
                    proc.kill()
        if errors:
            raise ReplayError(f"rendering {path} failed: {errors[0]}")
        _join(parts, path)


class _FrameCounter:
    """Frames done here and by the worker processes (their messages), reported as one count."""

    def __init__(self, messages: multiprocessing.Queue, done: Callable[[int], None]) -> None:
        self._messages = messages
        self._done = done
        self.frames = 0
        self.finished = 0
        self.errors: list[str] = []

    def add_local_frame(self) -> None:
        """One frame rendered in this process; the workers' news read on the way."""
        self.frames += 1
        while True:
            try:
                self._handle(*self._messages.get_nowait())
            except queue_module.Empty:
                break
        self._done(self.frames)

    def _handle(self, kind: str, value: object) -> None:
        if kind == "frame":
            self.frames += 1
            self._done(self.frames)
        else:
            self.finished += 1
            if value is not None:
                self.errors.append(str(value))

    def wait(self, procs: Sequence[multiprocessing.process.BaseProcess]) -> list[str]:
        """Count the workers' frames until each has finished; their errors (a worker that died says so)."""
        while self.finished < len(procs):
            try:
                self._handle(*self._messages.get(timeout=1.0))
            except queue_module.Empty:
                dead = [p for p in procs if p.exitcode not in (None, 0)]
                if dead:
                    return [*self.errors, f"a worker process exited with code {dead[0].exitcode}"]
        return self.errors


def _join(parts: Sequence[Path], path: Path) -> None:
    """Concatenate H.264 segments into ``path`` without re-encoding (ffmpeg's concat demuxer)."""
    listing = parts[0].parent / "parts.txt"
    listing.write_text("".join(f"file '{p.name}'\n" for p in parts), encoding="utf-8")
    cmd = [ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "concat", "-safe", "0", "-i", str(listing)]
    result = subprocess.run([*cmd, "-c", "copy", "-movflags", "+faststart", str(path)], capture_output=True, text=True)
    if result.returncode != 0:
        first = (result.stderr.strip().splitlines() or ["no message"])[0]
        raise ReplayError(f"ffmpeg failed joining the segments of {path}: {first}")
