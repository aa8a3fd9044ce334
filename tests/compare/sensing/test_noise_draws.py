"""Noise draws shared by the cameras seeded alike: exactly each camera's own generator's draws."""

from __future__ import annotations

import numpy as np
import pytest

from compare.sensing import DepthCamera, DepthNoise, load_workcell, make_data, noise_draws
from compare.sensing.noise_draws import clear_shared_draws, shared_draws

SHAPE = (6, 5)


def _own(seed: int, frames: int, normal: bool, dropout: float) -> list[tuple[np.ndarray | None, np.ndarray | None]]:
    """What ``default_rng(seed)`` draws, frame by frame, as a camera of its own drew it."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(frames):
        z = rng.standard_normal(SHAPE, dtype=np.float32) if normal else None
        m = rng.random(SHAPE, dtype=np.float32) < dropout if dropout > 0 else None
        out.append((z, m))
    return out


def _equal(got, want) -> bool:
    return all(
        (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))
        for (a, b) in zip(got, want, strict=True)
    )


@pytest.fixture(autouse=True)
def _fresh():
    clear_shared_draws()
    yield
    clear_shared_draws()


@pytest.mark.parametrize(("normal", "dropout"), [(True, 0.3), (True, 0.0), (False, 0.3)])
def test_two_cameras_get_their_own_generators_draws_and_share_them(normal: bool, dropout: float) -> None:
    want = _own(11, 4, normal, dropout)
    first, second = shared_draws(11, SHAPE, normal, dropout), shared_draws(11, SHAPE, normal, dropout)
    got_first = [first.next_frame() for _ in range(4)]
    got_second = [second.next_frame() for _ in range(4)]
    assert all(_equal(g, w) for g, w in zip(got_first, want, strict=True))
    assert all(_equal(g, w) for g, w in zip(got_second, want, strict=True))
    kept = 0 if not normal else 1
    assert got_second[2][1 - kept] is got_first[2][1 - kept]  # read back, not drawn again
    other = shared_draws(12, SHAPE, normal, dropout).next_frame()
    assert not _equal(other, want[0])


def test_past_the_budget_cameras_continue_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    frame_bytes = SHAPE[0] * SHAPE[1] * 5
    monkeypatch.setattr(noise_draws, "BUDGET_BYTES", 2 * frame_bytes)  # two frames kept
    want = _own(3, 6, True, 0.2)
    a, b = shared_draws(3, SHAPE, True, 0.2), shared_draws(3, SHAPE, True, 0.2)
    got_a = [a.next_frame() for _ in range(3)]  # frame 2 does not fit: a draws it itself
    got_b = [b.next_frame() for _ in range(6)]
    got_a += [a.next_frame() for _ in range(3)]
    assert all(_equal(g, w) for g, w in zip(got_a, want, strict=True))
    assert all(_equal(g, w) for g, w in zip(got_b, want, strict=True))
    # A new series drops the least recently read one to fit; that one's cameras go on exactly.
    c = shared_draws(4, SHAPE, True, 0.2)
    c_first = c.next_frame()
    assert _equal(c_first, _own(4, 1, True, 0.2)[0])
    late = shared_draws(3, SHAPE, True, 0.2)  # its series was dropped: drawn again from the seed
    assert all(_equal(late.next_frame(), w) for w in want[:3])


def test_no_budget_keeps_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(noise_draws, "BUDGET_BYTES", 0)
    want = _own(5, 3, True, 0.1)
    for _ in range(2):
        draws = shared_draws(5, SHAPE, True, 0.1)
        assert all(_equal(draws.next_frame(), w) for w in want)


def test_cameras_render_the_same_noisy_frames_with_and_without_kept_draws(monkeypatch: pytest.MonkeyPatch) -> None:
    model = load_workcell()
    data = make_data(model)
    noise = DepthNoise(0.01, proportional=True, dropout=0.05)
    frames = {}
    for budget in (0, 1 << 30, 1 << 30):  # own draws; first camera keeping them; second reading them
        monkeypatch.setattr(noise_draws, "BUDGET_BYTES", budget)
        cam = DepthCamera(model, noise=noise, seed=9)
        try:
            frames.setdefault(budget, []).append([cam.render_depth(data) for _ in range(3)])
        finally:
            cam.close()
    own, (kept, read) = frames[0][0], frames[1 << 30]
    for a, b, c in zip(own, kept, read, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    assert not np.array_equal(own[0], own[1])  # a new draw each frame
