"""docs/config.md is generated from the config models and is up to date."""

from __future__ import annotations

import re

import pytest
from pydantic import BaseModel

from compare import config_doc
from compare.config import Config, ScenarioConfig


def test_committed_config_reference_is_up_to_date():
    assert config_doc.DOC_PATH.read_text(encoding="utf-8") == config_doc.render(), (
        "docs/config.md is out of date: run `python -m compare.config_doc`"
    )


def _rows(text: str) -> dict[str, list[list[str]]]:
    """Table rows of the generated file, by section heading."""
    out: dict[str, list[list[str]]] = {}
    heading = ""
    for line in text.splitlines():
        if line.startswith("#"):
            heading = line.lstrip("# ").strip("`")
        elif line.startswith("| `"):
            out.setdefault(heading, []).append([c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]])
    return out


def test_every_key_of_every_section_is_documented_once():
    rows = _rows(config_doc.render())
    for section, info in Config.model_fields.items():
        model = info.annotation if isinstance(info.annotation, type) else info.annotation.__args__[0]
        heading = f"[{section}]" if section != "levels" else "[[levels]]"
        keys = [r[0].strip("`") for r in rows[heading]]
        assert keys == list(model.model_fields), section


@pytest.mark.parametrize(
    ("section", "key", "unit", "default"),
    [
        ("[scenario]", "duration_s", "s", "`70`"),
        ("[scenario]", "drive_bandwidth_rad_s", "rad/s", "`100`"),
        ("[scenario]", "start_q", "rad", "`unset`"),
        ("[random]", "person_speed_mps", "m/s", "`[0.5, 1.6]`"),
        ("[sensor]", "dropout", "–", "`0`"),
        ("[hardware]", "max_acceleration_rad_s2", "rad/s²", "`4`"),
        ("[[person.keyframes]]", "t", "s", "**required**"),
        ("joint_limit", "activation_margin", "rad", "`0.05`"),
        ("wall_box", "activation_margin", "m", "`0.03`"),
        ("obstacle_distance", "safety_distance", "m", "`0.35`"),
        ("[methods.settings.hqp-<solver>]", "tolerance", "rad/s or m/s", "`unset`"),
    ],
)
def test_units_and_defaults_come_from_the_models(section, key, unit, default):
    row = {r[0].strip("`"): r for r in _rows(config_doc.render())[section]}[key]
    assert row[-3:-1] == [default, unit] or row[1:3] == [default, unit]


def test_keys_whose_unit_depends_on_the_task_type_say_so():
    text = config_doc.render()
    assert "- `activation_margin`: rad in `joint_limit`; m in `wall_box`, `virtual_wall`, `obstacle_distance`" in text


def test_a_key_without_a_meaning_stops_the_generator():
    class Undocumented(BaseModel):
        """A section.

        Attributes:
            known: Documented [m].
        """

        known: float = 1.0
        forgotten: float = 2.0

    with pytest.raises(config_doc.ConfigDocError, match=r"section\.forgotten: no meaning"):
        config_doc._model_rows(Undocumented, "section")


@pytest.mark.parametrize(
    ("name", "doc", "unit"),
    [
        ("max_age_s", "Stale after this.", "s"),
        ("std_rad_s", "σ of the noise.", "rad/s"),
        ("rho_m", "Half side [m].", "m"),
        ("velocity_norm_max", "Norm [rad/s] of the damping.", "rad/s"),
        ("dropout", "Fraction in [0, 1).", "–"),
        ("inject", "The `[[faults.inject]]` tables.", "–"),
    ],
)
def test_unit_of_a_key(name, doc, unit):
    assert config_doc.unit_of(name, doc) == unit


def test_scenario_attributes_are_parsed_from_the_docstring():
    docs = config_doc.attribute_docs(ScenarioConfig)
    assert docs["duration_s"] == "Simulated time [s], before ``time_scale``."
    assert set(docs) == set(ScenarioConfig.model_fields)
