"""The stored lexicographic reference of the bench's QP states.

Every backend of the HQP cascade is judged against the same reference: for each state of
:func:`bench_states` (the three case-2 states and :data:`~compare.bench.qp_states.RANDOM_COUNT`
random ones from :data:`~compare.bench.qp_states.RANDOM_SEED`), the level objectives and the
command of :func:`qp_baseline.lexicographic.lexicographic_reference` (one QP per level on
[q̇, w], explicit slacks, no null-space elimination, solved to high accuracy, each level's
optimality conditions checked). It is computed once and kept in :data:`REFERENCE_FILE` with the
states themselves and how it was made, so every bench run compares like with like; a changed
hierarchy or state generator shows up as a fingerprint mismatch instead of a silent drift.

Regenerate (≈ 15 s)::

    python -m compare.bench.qp_reference            # writes compare/bench/data/qp_reference.json
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import robots
from compare.arguments import ArgumentParser, output_path
from compare.bench.qp_states import RANDOM_COUNT, RANDOM_SEED, QpState, apply_qp_state, case2_qp_states, random_states
from compare.bench.solver_cases import case2_description, case2_hierarchy
from compare.versions import versions
from qp_baseline.lexicographic import REFERENCE_TOLERANCES, lexicographic_reference
from robots import Robot

REFERENCE_FILE = Path(__file__).parent / "data" / "qp_reference.json"
"""Where the reference is stored (in the repository, next to the bench)."""

REGULARIZATION = 1e-9
"""ε of the reference's task levels: the HQP cascade's default."""


class ReferenceMismatch(RuntimeError):
    """The stored reference was made for other states or another hierarchy."""


@dataclass(frozen=True)
class ReferenceEntry:
    """The reference of one state.

    Attributes:
        state: The state.
        objectives: Level objectives :math:`f_k` of the reference command, one per task level.
        qdot: The reference command (minimum-norm lexicographic optimum) [rad/s]. Shape (n,).
        kkt: Largest primal/dual residual or duality gap over its level QPs.
    """

    state: QpState
    objectives: np.ndarray
    qdot: np.ndarray
    kkt: float


def bench_states(robot: Robot) -> list[QpState]:
    """The case-2 states, then the random ones (seed :data:`RANDOM_SEED`, :data:`RANDOM_COUNT` states)."""
    return case2_qp_states(robot) + random_states(robot, RANDOM_COUNT, RANDOM_SEED)


FINGERPRINT_DIGITS = 10
"""Significant digits of every float in :func:`fingerprint`."""


def _rounded(value: Any) -> Any:
    """``value`` with every float rounded to :data:`FINGERPRINT_DIGITS` significant digits."""
    if isinstance(value, float):
        return float(f"{value:.{FINGERPRINT_DIGITS - 1}e}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v) for v in value]
    return value


def fingerprint(states: list[QpState], robot: Robot) -> str:
    """SHA-256 of the robot's case-2 hierarchy description and the states (what the reference depends on).

    Floats enter rounded to :data:`FINGERPRINT_DIGITS` significant digits: the state generator
    draws its gains through ``np.exp``, whose last bit depends on the CPU's SIMD kernels (AVX2 and
    AVX-512 differ), and a reference is valid for states one rounding apart.
    """
    payload = json.dumps(
        _rounded({"hierarchy": case2_description(robot), "states": [s.to_dict() for s in states]}), sort_keys=True
    )
    return hashlib.sha256(payload.encode()).hexdigest()


def compute_reference(robot: Robot, states: list[QpState]) -> list[ReferenceEntry]:
    """The lexicographic reference of every state (see :mod:`qp_baseline.lexicographic`)."""
    hierarchy = case2_hierarchy(robot)
    out = []
    for state in states:
        apply_qp_state(hierarchy, state)
        ref, _ = lexicographic_reference(hierarchy, robot, robot.kinematics(state.bench.q), state.dt, REGULARIZATION)
        out.append(ReferenceEntry(state, ref.objectives, ref.qdot, ref.worst_kkt))
    return out


def write_reference(path: Path = REFERENCE_FILE) -> dict[str, Any]:
    """Compute the reference of :func:`bench_states` and write it (JSON, floats round-trip)."""
    robot = robots.load(robots.DEFAULT_ROBOT)
    states = bench_states(robot)
    t0 = time.perf_counter()
    entries = compute_reference(robot, states)
    info = versions()
    payload = {
        "made_with": {
            "command": "python -m compare.bench.qp_reference",
            "generator": (
                f"compare.bench.qp_states: case2_qp_states + random_states(n={RANDOM_COUNT}, seed={RANDOM_SEED})"
            ),
            "solver": "qp_baseline.lexicographic.lexicographic_reference (Clarabel + active-set polish, certified)",
            "regularization": REGULARIZATION,
            "tolerances": {
                "primal": REFERENCE_TOLERANCES.primal,
                "gap": REFERENCE_TOLERANCES.gap,
                "level": REFERENCE_TOLERANCES.level,
            },
            "seconds": round(time.perf_counter() - t0, 1),
            "versions": {k: info.get(k) for k in ("project", "numpy", "qpsolvers", "clarabel", "daqp", "pin")},
        },
        "fingerprint": fingerprint(states, robot),
        "levels": [level["name"] for level in case2_description(robot)],
        "states": [
            {**e.state.to_dict(), "objectives": e.objectives.tolist(), "qdot": e.qdot.tolist(), "kkt": e.kkt}
            for e in entries
        ],
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    # One state per line: small, and a regenerated file diffs state by state.
    head = json.dumps({k: v for k, v in payload.items() if k != "states"}, indent=1)[:-2]
    lines = ",\n".join("  " + json.dumps(item) for item in payload["states"])
    path.write_text(f'{head},\n "states": [\n{lines}\n ]\n}}\n', encoding="utf-8")
    return payload


def load_reference(path: Path = REFERENCE_FILE, check: bool = True) -> list[ReferenceEntry]:
    """Read the stored reference.

    Args:
        path: The reference file.
        check: Refuse a file whose fingerprint differs from the current :func:`bench_states`.

    Raises:
        FileNotFoundError: No reference file.
        ReferenceMismatch: ``check`` and the file was made for other states or another hierarchy.
    """
    data = json.loads(path.read_text(encoding="utf-8"))
    entries = [
        ReferenceEntry(
            QpState.from_dict(item),
            np.array(item["objectives"], dtype=float),
            np.array(item["qdot"]),
            float(item["kkt"]),
        )
        for item in data["states"]
    ]
    if check:
        stored = data.get("fingerprint")
        robot = robots.load(robots.DEFAULT_ROBOT)
        now = fingerprint(bench_states(robot), robot)
        if stored != now:
            raise ReferenceMismatch(
                f"{path} was made for other states or another hierarchy (fingerprint {str(stored)[:12]} ≠ "
                f"{now[:12]}): regenerate it with `python -m compare.bench.qp_reference`"
            )
    return entries


def main(argv: list[str] | None = None) -> int:
    """Regenerate the stored reference; returns the exit code."""
    parser = ArgumentParser(
        prog="python -m compare.bench.qp_reference",
        description="Compute the lexicographic reference (level objectives and command [rad/s]) of the bench's\n"
        f"QP states (three case-2 states and {RANDOM_COUNT} random ones) and write it as JSON (about 15 s).",
    )
    parser.add_argument(
        "--out",
        type=output_path,
        default=REFERENCE_FILE,
        help="output file (default: compare/bench/data/qp_reference.json, the stored reference)",
    )
    args = parser.parse_args(argv)
    payload = write_reference(args.out)
    worst = max(s["kkt"] for s in payload["states"])
    print(f"wrote {args.out}: {len(payload['states'])} states, worst KKT residual {worst:.2g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
