"""The avoidable family: redraws until a run is labelled avoidable, and the seed's draws are reproducible."""

from __future__ import annotations

from pathlib import Path

from compare.campaign import avoidable
from compare.config import load_config
from compare.scenarios.random_scenario import realize

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def test_draw_zero_is_the_seed_and_redraws_differ_reproducibly(jaco):
    config, _ = load_config(CONFIGS / "random_avoidable.toml")
    assert realize(config, jaco) == realize(config, jaco, draw=0)
    one = realize(config, jaco, draw=1)
    assert one == realize(config, jaco, draw=1)
    assert one.person.keyframes != realize(config, jaco).person.keyframes


def test_realize_avoidable_keeps_the_first_draw_labelled_avoidable(jaco, monkeypatch):
    config, _ = load_config(CONFIGS / "random_avoidable.toml", {"oracle.max_draws": 5})
    seen = []

    def fake(candidate, robot, cache_dir, stop_at_violation=False, certificate=True):
        seen.append((candidate.person.keyframes, stop_at_violation, certificate))
        return {"label": "avoidable" if len(seen) == 3 else "undecided", "min_distance_m": 0.4}

    monkeypatch.setattr(avoidable, "run_verdict", fake)
    chosen, entry = avoidable.realize_avoidable(config, jaco, None)
    assert entry["draws"] == 3 and entry["avoidable_draw_found"] is True
    assert chosen == realize(config, jaco, draw=2)
    assert all(stop for _, stop, _ in seen)  # rejected draws stop at their first violation
    assert not any(cert for _, _, cert in seen)  # no certificate is searched for a draw that is redrawn


def test_realize_avoidable_marks_a_seed_without_an_avoidable_draw(jaco, monkeypatch):
    config, _ = load_config(CONFIGS / "random_avoidable.toml", {"oracle.max_draws": 2})
    monkeypatch.setattr(avoidable, "run_verdict", lambda *a, **k: {"label": "undecided"})
    chosen, entry = avoidable.realize_avoidable(config, jaco, None)
    assert entry == {"label": "undecided", "draws": 2, "avoidable_draw_found": False, "draw": 1}
    assert chosen == realize(config, jaco, draw=1)
