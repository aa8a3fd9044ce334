"""A short case-2 run with depth sensing (tpik and mink), written once for the replay tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from compare.config import load_config
from compare.run import run_scenario

CONFIGS = Path(__file__).resolve().parents[3] / "configs"


@pytest.fixture(scope="session")
def case2_run(tmp_path_factory) -> Path:
    """Case 2 at a tenth of its pace (4 s, the person reaches in by 1.4 s), depth sensing, two methods."""
    out = tmp_path_factory.mktemp("replay") / "case2"
    config, text = load_config(CONFIGS / "case2.toml", {"scenario.time_scale": 0.1})
    config = config.model_copy(update={"methods": config.methods.model_copy(update={"names": ["tpik", "mink"]})})
    run_scenario(config, out, config_text=text, progress=False, make_plots=False)
    return out
