"""The loop's timing and its reactions to failures and to blind or stale sensing."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class LoopSettings:
    """Timing and safety reactions of the loop.

    Attributes:
        dt: Control period [s].
        duration_s: Simulated (or wall) time to run [s].
        sensing_period_s: Period of obstacle updates [s] (1/30 s).
        fallback: ``zero`` or ``hold_last`` (last safe command, decaying to zero).
        fallback_decay_s: Decay time of ``hold_last`` [s].
        max_sensing_age_s: An estimate older than this is stale → zero velocity [s].
        stop_when_blind: Command zero velocity while sensing is blind or stale.
        stale_frame_periods: A sensing update whose frame stamp is more than this many sensing
            periods older than the loop time is stale (frozen or delayed frame) → zero velocity
            at that update; ``None`` disables the check (then only ``max_sensing_age_s`` applies).
        deadline_s: A solve longer than this is a deadline miss (``deadline_miss`` column) [s];
            None = the control period ``dt`` (a solver time limit, when one is set, replaces it).
    """

    dt: float = 0.01
    duration_s: float = 10.0
    sensing_period_s: float = 1.0 / 30.0
    fallback: str = "zero"
    fallback_decay_s: float = 0.2
    max_sensing_age_s: float = 0.2
    stop_when_blind: bool = True
    stale_frame_periods: float | None = 1.5
    deadline_s: float | None = None
