"""The format of critical-speed results: their files, the swept speed ranges, and reading them back.

``tpik-compare critical-speed`` (:mod:`compare.campaign.critical_speed`) writes them; the claims
and the plots (:mod:`compare.analysis.claims`, :mod:`compare.analysis.plots_critical`) read them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

TORSO_RANGE_MPS = (0.1, 1.6)
"""Swept torso (walking) speeds [m/s]: ISO 13855's 1.6 m/s at the top."""
HAND_RANGE_MPS = (0.1, 2.0)
"""Hand speeds tied to them [m/s]: ISO 13855's 2.0 m/s at the top."""
CRITICAL_SPEED_FILE = "critical_speed.json"
DETAIL_FILE = "critical_speed_detail.json"
CLAIMS_FILE = "claims_at_critical.json"
PLOT_FILE = "critical_speed.png"


def hand_speed(torso_mps: float) -> float:
    """Hand speed tied to a torso speed [m/s]: the same fraction of both ranges on a log scale."""
    return float(log_map(np.asarray(torso_mps, dtype=float), TORSO_RANGE_MPS, HAND_RANGE_MPS))


def log_map(x: np.ndarray, src: tuple[float, float], dst: tuple[float, float]) -> np.ndarray:
    """Map ``x`` from the range ``src`` to ``dst`` keeping its fraction on a log scale (vectorised)."""
    frac = np.log(np.clip(x, 1e-9, None) / src[0]) / math.log(src[1] / src[0])
    return dst[0] * (dst[1] / dst[0]) ** frac


def load_critical(out_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """``critical_speed.json`` and ``critical_speed_detail.json`` of a directory."""
    out_dir = Path(out_dir)
    return (
        json.loads((out_dir / CRITICAL_SPEED_FILE).read_text(encoding="utf-8")),
        json.loads((out_dir / DETAIL_FILE).read_text(encoding="utf-8")),
    )
