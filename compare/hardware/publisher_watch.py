"""Who publishes on the topics the bridge commands and reads, as the ROS master knows it (no ROS import).

ROS 1 lets any node that reaches the master publish on the driver's command topic; the driver
executes whatever arrives. The bridge therefore asks the master (``getSystemState``) every
``period_s`` who publishes on

* the **command topics** (``hardware.velocity_topic`` and the driver's other inputs that move the
  arm, ``hardware.other_command_topics``): anyone but the bridge itself is a *foreign command
  publisher*;
* the **read topics** (joint states, depth, camera info): the publishers found at start are the
  only ones allowed; any other is a *second publisher*.

The first poll is made at start (:meth:`PublisherWatch.snapshot`, refusing the start on a
finding); later polls run on their own thread and report the first finding through
``on_halt(cause)``, once. A master that does not answer for ``silence_s`` is a finding too:
nobody can then tell who publishes; so is the bridge's own node shut down (the master shuts a
node down when another registers under its name, which would then pass for the bridge). What
the master does not know (a node told to connect to a
publisher through its own XML-RPC API, ``publisherUpdate``) is not seen here; messages from such a
publisher on a read topic are caught by their sender's caller id
(:class:`~compare.hardware.validation.SenderCheck`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from itertools import pairwise
from typing import Any

from compare.hardware.exceptions import StartRefused
from compare.hardware.master_api import MasterCallFailed

log = logging.getLogger(__name__)

Publishers = Mapping[str, Sequence[str]]
"""Topic → caller ids of its publishers."""


def foreign_command_cause(caller_id: str) -> str:
    """The halt cause for a publisher on a command topic other than the bridge."""
    return f"foreign command publisher {caller_id}"


def second_publisher_cause(caller_id: str, topic: str) -> str:
    """The halt cause for a publisher on a read topic other than the one found at start."""
    return f"second publisher {caller_id} on {topic}"


class PublisherWatch:
    """Polls the master for the publishers of the command and read topics; halts on a stranger.

    Args:
        lookup: One ``getSystemState`` (topic → publishers); raises
            :class:`~compare.hardware.master_api.MasterCallFailed` when the master does not answer.
        own_caller_id: The bridge's node name (allowed on the command topics).
        command_topics: Topics only the bridge may publish on.
        read_topics: Topics whose publishers at :meth:`snapshot` are the only ones allowed.
        period_s: Time between polls [s].
        silence_s: A master unanswered for this long is a finding [s].
        on_halt: Called once, from the watch thread, with the cause of the first finding.
        clock: Monotonic time [s].
        self_check: Called at every poll: a cause when the bridge itself cannot be trusted any
            more (its node shut down), else None.
    """

    def __init__(
        self,
        lookup: Callable[[], Publishers],
        own_caller_id: str,
        command_topics: Sequence[str],
        read_topics: Sequence[str],
        period_s: float,
        silence_s: float,
        on_halt: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
        self_check: Callable[[], str | None] | None = None,
    ) -> None:
        if period_s <= 0.0 or silence_s < period_s:
            raise ValueError(f"need 0 < period_s <= silence_s, got {period_s}, {silence_s}")
        self._lookup = lookup
        self.own_caller_id = own_caller_id
        self.command_topics = tuple(command_topics)
        self.read_topics = tuple(read_topics)
        self.period_s = float(period_s)
        self.silence_s = float(silence_s)
        self._on_halt = on_halt
        self._clock = clock
        self._self_check = self_check
        self.allowed: dict[str, frozenset[str]] = {}
        self.cause: str | None = None
        self.cause_t: float | None = None
        self.poll_starts: deque[float] = deque(maxlen=100_000)
        self.failed_polls = 0
        self._last_answer_t: float | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def findings(self, publishers: Publishers) -> list[str]:
        """Every cause in ``publishers`` (empty: only the bridge commands, only the known publishers feed it)."""
        causes = []
        for topic in self.command_topics:
            causes += [foreign_command_cause(c) for c in sorted(publishers.get(topic, ())) if c != self.own_caller_id]
        for topic in self.read_topics:
            allowed = self.allowed.get(topic, frozenset())
            causes += [second_publisher_cause(c, topic) for c in sorted(publishers.get(topic, ())) if c not in allowed]
        return causes

    def snapshot(self) -> dict[str, list[str]]:
        """The first poll, at start: fixes the read topics' publishers.

        Returns:
            Topic → publishers found (for the report).

        Raises:
            StartRefused: the master does not answer, a read topic has several publishers, or
                someone else publishes on a command topic.
        """
        try:
            publishers = self._poll()
        except MasterCallFailed as exc:
            raise StartRefused(f"cannot tell who publishes on the driver's topics: {exc}") from None
        several = {t: sorted(publishers.get(t, ())) for t in self.read_topics if len(publishers.get(t, ())) > 1}
        if several:
            topic, names = next(iter(several.items()))
            raise StartRefused(f"{len(names)} publishers on {topic} ({', '.join(names)}): only one may feed the bridge")
        self.allowed = {t: frozenset(publishers.get(t, ())) for t in self.read_topics}
        causes = self.findings(publishers)
        if causes:
            raise StartRefused(causes[0])
        return {t: sorted(publishers.get(t, ())) for t in self.command_topics + self.read_topics}

    def start(self) -> None:
        """Poll every ``period_s`` on a daemon thread until :meth:`stop` or the first finding."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="tpik-hw-publishers", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """End the polls (waits for the one in flight)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=self.period_s + 5.0)

    def _poll(self) -> Publishers:
        self.poll_starts.append(self._clock())
        publishers = self._lookup()
        self._last_answer_t = self._clock()
        return publishers

    def poll_once(self) -> str | None:
        """One poll: the cause of a finding (reported through ``on_halt``), or None."""
        t = self._clock()
        own = self._self_check() if self._self_check is not None else None
        try:
            causes = [own] if own is not None else self.findings(self._poll())
        except MasterCallFailed as exc:
            self.failed_polls += 1
            since = self._last_answer_t if self._last_answer_t is not None else t
            silent = self._clock() - since
            if silent < self.silence_s:
                log.debug("publisher watch: %s", exc)
                return None
            causes = [f"no answer from the ROS master for {1e3 * silent:.0f} ms: cannot tell who publishes ({exc})"]
        if not causes:
            return None
        self.cause, self.cause_t = causes[0], t
        self._on_halt(causes[0])
        return causes[0]

    def _run(self) -> None:
        next_t = self._clock()
        while not self._stop.is_set():
            if self.poll_once() is not None:
                return
            next_t = max(next_t + self.period_s, self._clock())
            self._stop.wait(max(0.0, next_t - self._clock()))

    def report(self, origin: float) -> dict[str, Any]:
        """Polls and finding, times in seconds since ``origin`` (monotonic), for ``summary.json``."""
        starts = [t - origin for t in self.poll_starts if t >= origin]
        gaps = [b - a for a, b in pairwise(starts)]
        return {
            "period_s": self.period_s,
            "silence_s": self.silence_s,
            "own_caller_id": self.own_caller_id,
            "allowed_publishers": {t: sorted(v) for t, v in self.allowed.items()},
            "polls": len(starts),
            "failed_polls": self.failed_polls,
            "poll_interval_max_ms": 1e3 * max(gaps) if gaps else None,
            "cause": self.cause,
            "cause_t_s": self.cause_t - origin if self.cause_t is not None else None,
        }
