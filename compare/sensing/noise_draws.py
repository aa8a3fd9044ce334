"""The random draws of a depth camera's noise, drawn once per process for every camera seeded alike.

A :class:`~compare.sensing.renderer.DepthCamera` draws, for each noisy frame, a standard normal
per pixel (when ``std_m > 0``) and then a uniform per pixel for the dropout (when ``dropout > 0``),
from ``numpy.random.default_rng(seed)``. The draws depend on the seed, the frame size and which of
the two are drawn, never on the scene: every method of one scenario run gets the same noise. A
campaign runs the methods of a seed one after the other in one process, so the draws are made by
the first and read back by the others (:func:`shared_draws`). What a camera receives is exactly
what its own generator would have drawn, frame by frame: the frames kept are the generator's
output, and past them a camera continues from the generator's state after the last frame kept.

The draws kept in a process are bounded by :data:`BUDGET_BYTES` (the environment variable
``TPIK_NOISE_CACHE_MB`` sets it; 0 keeps none): the series a camera asked for least recently are
dropped first, and a series that does not fit stops growing (its cameras draw the rest themselves).
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

_ENV = "TPIK_NOISE_CACHE_MB"
_DEFAULT_MB = 768.0


def _budget_bytes() -> int:
    text = os.environ.get(_ENV, "")
    try:
        mb = float(text) if text.strip() else _DEFAULT_MB
    except ValueError:
        mb = _DEFAULT_MB
    return max(0, int(mb * 2**20))


BUDGET_BYTES = _budget_bytes()
"""Bytes of draws kept per process (about 1.1 MB per 512 × 424 frame with noise and dropout)."""


@dataclass(frozen=True)
class DrawKey:
    """What fixes a camera's draws: the generator's seed, the frame shape, which draws a frame takes."""

    seed: int
    shape: tuple[int, int]
    normal: bool
    dropout: float


class NoiseSeries:
    """The frames of draws of one :class:`DrawKey`, kept while the budget allows."""

    def __init__(self, key: DrawKey, rng: np.random.Generator | None = None) -> None:
        self.key = key
        self._rng = rng if rng is not None else np.random.default_rng(key.seed)
        self.normals: list[np.ndarray] = []
        self.dropped: list[np.ndarray] = []
        self.frozen = False
        self.nbytes = 0

    @property
    def frames(self) -> int:
        """Frames kept."""
        return max(len(self.normals), len(self.dropped))

    def draw_next(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Draw the next frame from the series' generator: (standard normals, dropped-pixel mask)."""
        key = self.key
        normal = self._rng.standard_normal(key.shape, dtype=np.float32) if key.normal else None
        dropped = self._rng.random(key.shape, dtype=np.float32) < key.dropout if key.dropout > 0.0 else None
        return normal, dropped

    def generator_after_kept(self) -> np.random.Generator:
        """A new generator in the state the series' generator has after the frames kept."""
        rng = np.random.default_rng()
        rng.bit_generator.state = self._rng.bit_generator.state
        return rng


class _Registry:
    """The series of this process, least recently asked for first, within :data:`BUDGET_BYTES`."""

    def __init__(self) -> None:
        self._series: OrderedDict[DrawKey, NoiseSeries] = OrderedDict()
        self._lock = threading.Lock()
        self.nbytes = 0

    def series(self, key: DrawKey) -> NoiseSeries:
        with self._lock:
            found = self._series.get(key)
            if found is None:
                found = self._series[key] = NoiseSeries(key)
            self._series.move_to_end(key)
            return found

    def frame(self, series: NoiseSeries, k: int) -> tuple[np.ndarray | None, np.ndarray | None] | None:
        """Frame ``k`` of ``series`` (drawn and kept when it is the next one and fits), else None."""
        with self._lock:
            if k < series.frames:
                return (series.normals[k] if series.normals else None), (series.dropped[k] if series.dropped else None)
            if k > series.frames or series.frozen:
                return None
            size = int(np.prod(series.key.shape)) * (4 * series.key.normal + (series.key.dropout > 0.0))
            while self.nbytes + size > BUDGET_BYTES and self._drop_oldest(but=series):
                pass
            if self.nbytes + size > BUDGET_BYTES:
                series.frozen = True
                return None
            normal, dropped = series.draw_next()
            if normal is not None:
                series.normals.append(normal)
            if dropped is not None:
                series.dropped.append(dropped)
            series.nbytes += size
            self.nbytes += size
            return normal, dropped

    def _drop_oldest(self, but: NoiseSeries) -> bool:
        for key, series in self._series.items():
            if series is not but:
                del self._series[key]
                self.nbytes -= series.nbytes
                series.frozen = True  # its cameras go on privately; it no longer grows
                return True
        return False

    def clear(self) -> None:
        with self._lock:
            self._series.clear()
            self.nbytes = 0


_REGISTRY = _Registry()


class NoiseDraws:
    """One camera's draws, frame after frame: from the shared series, then from its own generator."""

    def __init__(self, key: DrawKey) -> None:
        self._series = _REGISTRY.series(key)
        self._next = 0
        self._own: NoiseSeries | None = None

    def next_frame(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The next frame's (standard normals, dropped-pixel mask); arrays shared: read only."""
        if self._own is None:
            got = _REGISTRY.frame(self._series, self._next)
            if got is not None:
                self._next += 1
                return got
            # Past the frames kept (this camera read all of them): go on privately from the state after them.
            self._own = NoiseSeries(self._series.key, self._series.generator_after_kept())
        return self._own.draw_next()


def shared_draws(seed: int, shape: tuple[int, int], normal: bool, dropout: float) -> NoiseDraws:
    """The draws of a camera seeded ``seed`` with frames of ``shape`` (module docstring)."""
    return NoiseDraws(DrawKey(int(seed), (int(shape[0]), int(shape[1])), bool(normal), float(dropout)))


def clear_shared_draws() -> None:
    """Drop every series kept in this process."""
    _REGISTRY.clear()
