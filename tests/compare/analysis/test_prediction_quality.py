"""The prediction's quality: error, bias and latency of an estimate against a known truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from compare.analysis.prediction_quality import CLOSING_MPS, estimate_errors, main


def test_a_delayed_scaled_estimate_has_its_latency_and_bias():
    dt = 0.01
    t = np.arange(0.0, 6.0, dt)
    truth = np.maximum(0.0, np.sin(t)) * 1.2  # closing in at up to 1.2 m/s half of the time
    lag = 7
    estimate = np.full_like(truth, np.nan)
    estimate[lag:] = 0.9 * truth[:-lag]  # 70 ms late, 10 % short
    out = estimate_errors(estimate, truth, dt)
    assert out["latency_s"] == pytest.approx(lag * dt)
    closing = truth[lag:] > CLOSING_MPS
    assert out["closing_samples"] == int(closing.sum())
    assert out["closing_bias_mps"] < 0.0  # late on the way up, short throughout
    assert out["bias_mps"] < 0.0


def test_a_perfect_estimate_has_no_error():
    truth = np.linspace(0.0, 1.0, 200)
    out = estimate_errors(truth.copy(), truth, 0.01)
    assert out["rms_error_mps"] == 0.0 and out["latency_s"] == 0.0 and out["closing_median_abs_error_mps"] == 0.0


def test_a_directory_that_is_no_run_is_one_line(tmp_path: Path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([str(tmp_path)])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and "neither a run" in err
