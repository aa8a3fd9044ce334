r"""The solving thread's CPU time with the hypervisor's steal taken out (simulation time limit).

In simulation a solve is judged by what it costs on a core of its own: the solving thread's
CPU time (``time.thread_time``, :mod:`compare.loop.deadline`). In a virtual machine that clock
also runs while the hypervisor has taken the virtual CPU away (*steal time*): a solve of
0.3 ms that such a pause lands on reads as 10–50 ms and would be refused as late, although on a
core of its own it would have answered at once. The guest kernel counts steal per virtual CPU
in ``/proc/stat`` (the 8th value of each ``cpuN`` line, in ``USER_HZ`` ticks, 10 ms here).

:class:`StealClock` measures one call as

.. math::  t_{own} = \Delta t_{thread} - \Delta s \cdot \tau

with :math:`\Delta s` the steal ticks counted on the virtual CPU the thread was on at the start
and at the end of the call (``sched_getcpu``) and :math:`\tau` the tick. A thread that moved
between two virtual CPUs during the call takes the larger of their two counts, not their sum:
it ran on one of them at a time, and a host pause lands on every virtual CPU at once (on a
loaded CI worker the sum counted such a pause twice, excusing twice the time it cost). Ticks are
whole: the true steal :math:`S` lies in :math:`((\Delta s - 1)\tau, (\Delta s + 1)\tau)`, so
:math:`t_{own}` is right to one tick either way; with no tick counted nothing is taken out (a
pause shorter than a tick stays in the solve's time). Reading ``/proc/stat`` costs ≈ 6 µs:
it is read at the start of every call and kept as read; it is parsed, and read again, only
for a call that looks late (:meth:`StealClock.own_elapsed_s`). Where there is no ``/proc/stat`` (not Linux) or no
``sched_getcpu``, the clock is the plain thread CPU time (:attr:`StealClock.available` False).
"""

from __future__ import annotations

import ctypes
import logging
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

log = logging.getLogger(__name__)

STAT = Path("/proc/stat")
STEAL_FIELD = 8
"""Index of the steal count in a ``cpuN`` line of ``/proc/stat`` (after the name: user, nice,
system, idle, iowait, irq, softirq, steal)."""


def steal_ticks(fields: Sequence[bytes] | Sequence[str]) -> int | None:
    """The steal count of one split ``cpu``/``cpuN`` line of ``/proc/stat`` [ticks]; None when malformed."""
    if len(fields) <= STEAL_FIELD or not fields[STEAL_FIELD].isdigit():
        return None
    return int(fields[STEAL_FIELD])


def parse_steal(text: bytes) -> tuple[int, ...] | None:
    """Steal ticks of each virtual CPU from the text of ``/proc/stat``; None when unreadable.

    Returns:
        ``steal[i]`` of ``cpu<i>`` (the aggregate ``cpu`` line is skipped).
    """
    out: list[int] = []
    for line in text.split(b"\n"):
        if not line.startswith(b"cpu"):
            if out:
                break  # the cpuN lines come first, together
            continue
        fields = line.split()
        if fields[0] == b"cpu":
            continue
        ticks = steal_ticks(fields)
        if ticks is None:
            return None
        out.append(ticks)
    return tuple(out) or None


_FDS: dict[Path, int | None] = {}
"""Open statistics files of this process (one descriptor per path, kept for the process's life)."""


def _stat_fd(stat: Path) -> int | None:
    if stat not in _FDS:
        try:
            _FDS[stat] = os.open(stat, os.O_RDONLY)
        except OSError:
            _FDS[stat] = None
    return _FDS[stat]


def _sched_getcpu() -> Callable[[], int] | None:
    try:
        fn = ctypes.CDLL(None, use_errno=True).sched_getcpu
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_int
    fn.argtypes = []
    return fn  # type: ignore[no-any-return]


class StealClock:
    """CPU time of one solve call without the hypervisor's steal (module docstring).

    Use: :meth:`begin` at the start of the call, :meth:`elapsed_s` (cheap, steal included)
    while it runs, :meth:`own_elapsed_s` (reads ``/proc/stat``) to judge a call that looks late.
    It is a :class:`qp_baseline.time_limits.CallClock`: the QP methods' budget shares it.

    Args:
        stat: The kernel's statistics file (a test passes its own).
    """

    def __init__(self, stat: Path = STAT) -> None:
        self.tick_s = 1.0 / float(os.sysconf("SC_CLK_TCK")) if hasattr(os, "sysconf") else 0.01
        self._getcpu = _sched_getcpu()
        self._fd = _stat_fd(stat)
        self.available = self._fd is not None and self._getcpu is not None and self._steal() is not None
        """Whether steal can be read here; when not, the clock is the plain thread CPU time."""
        if not self.available:
            log.debug("no per-CPU steal counter (%s): the solve time limit uses the plain CPU clock", stat)
        self._t0 = time.thread_time()
        self._wall0_ns = time.perf_counter_ns()
        self._cpu0 = 0
        self._raw0: bytes | None = None

    def _read(self) -> bytes | None:
        if self._fd is None:
            return None
        try:
            return os.pread(self._fd, 8192, 0)
        except OSError:
            return None

    def _steal(self) -> tuple[int, ...] | None:
        raw = self._read()
        return None if raw is None else parse_steal(raw)

    def begin(self) -> None:
        """Start measuring a call: thread CPU time, the CPU it runs on, every CPU's steal count."""
        if self.available:
            assert self._getcpu is not None
            self._cpu0 = self._getcpu()
            self._raw0 = self._read()  # parsed only for a call that looks late (stolen_s)
        self._wall0_ns = time.perf_counter_ns()  # just before the CPU start: the wall window encloses it
        self._t0 = time.thread_time()

    def began_s(self) -> float:
        """Thread CPU time when the current call began (:meth:`begin`) [s]."""
        return self._t0

    def began_wall_ns(self) -> int:
        """``time.perf_counter_ns()`` just before the current call's CPU start [ns]."""
        return self._wall0_ns

    def elapsed_s(self) -> float:
        """Thread CPU time since :meth:`begin` [s], steal included (cheap)."""
        return time.thread_time() - self._t0

    def stolen_s(self) -> float:
        """Steal counted since :meth:`begin` on the CPU the thread was on at its start and now [s].

        When the thread moved between the two, the larger of the two CPUs' counts (module docstring).
        """
        if not self.available or self._raw0 is None:
            return 0.0
        assert self._getcpu is not None
        now, cpu1 = self._steal(), self._getcpu()
        before = parse_steal(self._raw0)
        if now is None or before is None or len(now) != len(before):
            return 0.0
        cpus = {self._cpu0, cpu1}
        ticks = max((now[c] - before[c] for c in cpus if 0 <= c < len(now)), default=0)
        return max(0, ticks) * self.tick_s

    def own_elapsed_s(self) -> tuple[float, float]:
        """(CPU time since :meth:`begin` without the steal counted meanwhile, that steal) [s]."""
        took = self.elapsed_s()
        stolen = self.stolen_s()
        return max(0.0, took - stolen), stolen
