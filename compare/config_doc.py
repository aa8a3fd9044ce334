"""``docs/config.md``: every key of a scenario TOML, generated from the config models.

The keys, types, limits and defaults come from the pydantic models of :mod:`compare.config`
and the settings dataclasses of the methods; the meanings from their docstrings' ``Attributes``
sections; the task keys from the task registry (:func:`tpik.task_types`). A unit is the one in
brackets in the meaning (``[m]``), else the one the key's name ends with (``_s``, ``_m``,
``_rad_s``...). Regenerate after changing a model::

    python -m compare.config_doc          # writes docs/config.md
    python -m compare.config_doc --check  # exit 1 if docs/config.md is out of date

Raises :class:`ConfigDocError` for a key without a meaning: every key is documented.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import sys
import types
import typing
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, Literal

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from compare.arguments import ArgumentParser, output_path
from compare.config import Config
from compare.exceptions import CompareError
from qp_baseline.backends import BACKENDS
from qp_baseline.hqp import HqpSettings
from qp_baseline.mink_peer import POSTURE_PRESET, MinkSettings
from tpik.solver import TpikSettings
from tpik.tasks import BUILTIN_TASK_TYPES, get_task_type

DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "config.md"
"""The generated file."""

_UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_rad_s2", "rad/s²"),
    ("_rad_s", "rad/s"),
    ("_mps", "m/s"),
    ("_hz", "Hz"),
    ("_rad", "rad"),
    ("_us", "µs"),
    ("_m", "m"),
    ("_s", "s"),
)
_BRACKET_UNIT = re.compile(r"\[([^\[\],().`:]*[A-Za-zµ][^\[\],().`:]*)\]")


class ConfigDocError(CompareError):
    """A config key has no meaning in its model's docstring."""


def attribute_docs(cls: type) -> dict[str, str]:
    """The ``Attributes:`` (or ``Args:``) entries of a Google docstring, one line each."""
    out: dict[str, str] = {}
    current: str | None = None
    inside = False
    for line in inspect.cleandoc(cls.__doc__ or "").splitlines():
        if line.strip() in ("Attributes:", "Args:"):
            inside, current = True, None
            continue
        if not inside:
            continue
        if line.strip() and not line.startswith("    "):
            inside, current = False, None
            continue
        entry = re.match(r"^    (\w+)(?: \([^)]*\))?: (.*)$", line)
        if entry:
            current = entry[1]
            out[current] = entry[2].strip()
        elif current and line.strip():
            out[current] += " " + line.strip()
    return out


def _plain(text: str) -> str:
    """Docstring markup as Markdown: roles and double back-quotes become code spans."""
    text = re.sub(r":(?:math|data|class|func|meth|attr|mod):`~?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`").replace("\\|", "‖").replace("|", "\\|")


def unit_of(name: str, doc: str) -> str:
    """The unit of a key: in brackets in its meaning, else from its name's suffix; ``–`` for none."""
    found = _BRACKET_UNIT.search(doc)
    if found:
        return found[1].strip()
    for suffix, unit in _UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return "–"


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return ("inf" if value > 0 else "-inf") if math.isinf(value) else f"{value:g}"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"
    if value is None:
        return "unset"
    return str(value)


_SCALARS = {float: "number", int: "integer", bool: "true / false", str: "string", typing.Any: "any"}


def type_of(annotation: Any) -> str:
    """A reader's name of a field type: ``number``, ``"a" | "b"``, ``[3 numbers]``, ``list of tables``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation in _SCALARS:
        return _SCALARS[annotation]
    if origin is Literal:
        return " \\| ".join(f'"{a}"' for a in args)
    if origin in (typing.Union, types.UnionType):
        inner = [type_of(a) for a in args if a is not type(None)]
        return " or ".join(inner) + (" or unset" if type(None) in args else "")
    if origin is tuple:
        kinds = {type_of(a) for a in args if a is not Ellipsis}
        kind = kinds.pop() if len(kinds) == 1 else "values"
        return f"[{kind}, …]" if Ellipsis in args else f"[{len(args)} {kind}s]"
    if origin is list:
        inner = type_of(args[0]) if args else "values"
        return f"list of {inner}s" if inner.isalpha() else f"list of ({inner})"
    if origin in (dict, Mapping):
        return "table" if not args or args[1] is typing.Any else f"table of {type_of(args[1])}s"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    return str(annotation)


def limits_of(info: FieldInfo) -> str:
    """The bounds pydantic checks (``> 0``, ``≤ 10``, ``at least 1``)."""
    out = []
    for meta in info.metadata:
        for attr, symbol in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            value = getattr(meta, attr, None)
            if isinstance(meta, annotated_types.BaseMetadata) and value is not None:
                out.append(f"{symbol} {_toml(value)}")
        if isinstance(meta, annotated_types.MinLen) and meta.min_length:
            out.append(f"at least {meta.min_length}")
    return ", ".join(out)


def _default(info: FieldInfo) -> str:
    if info.default_factory is not None:
        value = info.default_factory()  # type: ignore[call-arg]
        return "–" if isinstance(value, BaseModel) else f"`{_toml(value)}`"
    if info.default is PydanticUndefined:
        return "**required**"
    return f"`{_toml(info.default)}`"


def _table(headers: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    return out + ["| " + " | ".join(row) + " |" for row in rows]


def _model_rows(model: type[BaseModel], where: str) -> tuple[list[list[str]], list[tuple[str, type[BaseModel]]]]:
    """Rows of a model's scalar keys, and its nested ``[[tables]]`` (list-of-model fields)."""
    docs = attribute_docs(model)
    rows: list[list[str]] = []
    nested: list[tuple[str, type[BaseModel]]] = []
    for name, info in model.model_fields.items():
        args = typing.get_args(info.annotation)
        if typing.get_origin(info.annotation) is list and args and issubclass_model(args[0]):
            nested.append((f"{where}.{name}", args[0]))
        if name not in docs:
            raise ConfigDocError(f"{where}.{name}: no meaning in the Attributes of {model.__name__}'s docstring")
        doc = docs[name]
        kind = type_of(info.annotation)
        limits = limits_of(info)
        rows.append(
            [
                f"`{name}`",
                kind + (f" ({limits})" if limits else ""),
                _default(info),
                unit_of(name, doc),
                _plain(doc),
            ]
        )
    return rows, nested


def issubclass_model(value: Any) -> bool:
    """Whether ``value`` is a pydantic model class."""
    return isinstance(value, type) and issubclass(value, BaseModel)


_HEADERS = ["key", "type", "default", "unit", "meaning"]


def _section(model: type[BaseModel], where: str, heading: str) -> Iterator[str]:
    rows, nested = _model_rows(model, where)
    summary = _plain(inspect.cleandoc(model.__doc__ or "").split("\n\n")[0].replace("\n", " "))
    yield from ["", f"## `{heading}`", "", summary, ""]
    yield from _table(_HEADERS, rows)
    for path, sub in nested:
        sub_rows, _ = _model_rows(sub, path)
        doc = _plain(inspect.cleandoc(sub.__doc__ or "").split("\n\n")[0].replace("\n", " "))
        yield from ["", f"### `[[{path}]]`", "", doc, ""]
        yield from _table(_HEADERS, sub_rows)


def _dataclass_rows(cls: type, where: str) -> list[list[str]]:
    docs = attribute_docs(cls)
    rows = []
    for f in dataclasses.fields(cls):
        if f.name not in docs:
            raise ConfigDocError(f"{where}.{f.name}: no meaning in the Attributes of {cls.__name__}'s docstring")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        annotation = typing.get_type_hints(cls)[f.name]
        doc = docs[f.name]
        rows.append([f"`{f.name}`", type_of(annotation), f"`{_toml(default)}`", unit_of(f.name, doc), _plain(doc)])
    return rows


def _methods_settings() -> Iterator[str]:
    yield from ["", "### `[methods.settings.tpik]` (and `tpik-<variant>`)", ""]
    yield "Settings of the paper's solver (`tpik.solver.TpikSettings`); `tpik-<variant>` sets `variant`."
    yield ""
    yield from _table(_HEADERS, _dataclass_rows(TpikSettings, "methods.settings.tpik"))
    yield from ["", "### `[methods.settings.hqp-<solver>]`", ""]
    yield (
        "Options of the HQP cascade (`qp_baseline.hqp.HqpSettings`). Every other key is a setting of the QP"
        " backend itself (its own name and unit, e.g. `eps_abs` for OSQP), applied over the defaults below."
    )
    yield ""
    yield from _table(_HEADERS, _dataclass_rows(HqpSettings, "methods.settings.hqp"))
    yield ""
    yield from _table(
        ["backend", "settings the cascade starts from (`qp_baseline.backends.BACKENDS`)"],
        [
            [f"`{name}`", f"`{_toml(dict(backend.defaults))}`" if backend.defaults else "its own defaults"]
            for name, backend in BACKENDS.items()
        ],
    )
    yield from ["", "### `[methods.settings.mink]` (and `mink-hard`, `mink-posture`)", ""]
    yield (
        "Settings of the mink peers (`qp_baseline.mink_peer.MinkSettings`). `mink-posture` starts from"
        f" `{_toml(dict(POSTURE_PRESET))}` (`qp_baseline.mink_peer.POSTURE_PRESET`, the values of mink's arm"
        " examples); its return weight is `level_cost_ratio`."
    )
    yield ""
    yield from _table(_HEADERS, _dataclass_rows(MinkSettings, "methods.settings.mink"))


def _task_types() -> Iterator[str]:
    builtin = [get_task_type(name) for name in BUILTIN_TASK_TYPES]
    units: dict[str, dict[str, list[str]]] = {}
    yield from ["", "### Task types (`type = ...` in `[[levels]] tasks`)", ""]
    yield (
        "Registered with `tpik.register_task` (docs/extending.md adds one). Thresholds and margins are in the"
        " unit of the task's σ, so the same key can carry different units in different task types."
    )
    for task_type in builtin:
        rows = []
        for key in task_type.keys:
            units.setdefault(key.name, {}).setdefault(key.unit or "–", []).append(task_type.name)
            default = (
                "**required**" if key.required else ("derived" if key.default is None else f"`{_toml(key.default)}`")
            )
            rows.append([f"`{key.name}`", default, key.unit or "–", _plain(key.doc)])
        yield from ["", f"#### `{task_type.name}`", "", _plain(task_type.summary) + ".", ""]
        yield from _table(["key", "default", "unit", "meaning"], rows)
    mixed = {k: v for k, v in units.items() if len(v) > 1}
    if mixed:
        yield from ["", "Keys whose unit depends on the task type:", ""]
        for key, by_unit in sorted(mixed.items()):
            listed = "; ".join(f"{unit} in {', '.join(f'`{n}`' for n in names)}" for unit, names in by_unit.items())
            yield f"- `{key}`: {listed}"


def render() -> str:
    """The whole of ``docs/config.md``."""
    out = [
        "# Configuration reference",
        "",
        "<!-- Generated by `python -m compare.config_doc` from compare/config.py, the methods' settings and the",
        "     task registry; do not edit by hand (tests/compare/test_config_doc.py checks it is up to date). -->",
        "",
        "A scenario is one TOML file (`configs/*.toml`); `tpik-compare run CONFIG` validates it whole first.",
        "Unknown keys, wrong types and values out of range are one error line naming the key (exit code 2).",
        "Units are SI (m, rad, s); positions are in the arm base frame. Defaults apply to keys left out.",
    ]
    for name, info in Config.model_fields.items():
        annotation = info.annotation
        args = typing.get_args(annotation)
        if issubclass_model(annotation):
            out += list(_section(annotation, name, f"[{name}]"))  # type: ignore[arg-type]
        elif typing.get_origin(annotation) is list and args and issubclass_model(args[0]):
            out += list(_section(args[0], name, f"[[{name}]]"))
        else:
            raise ConfigDocError(f"{name}: a top-level key that is not a section")
        if name == "levels":
            out += list(_task_types())
        if name == "methods":
            out += list(_methods_settings())
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write ``docs/config.md`` (``--check``: only compare, exit 1 when it is out of date)."""
    parser = ArgumentParser(
        prog="python -m compare.config_doc",
        description="Write the reference of every scenario TOML key (type, limits, default, unit, meaning),\n"
        "generated from the configuration models, to docs/config.md.",
    )
    parser.add_argument(
        "--out", type=output_path, default=DOC_PATH, help="the file to write or check (default: docs/config.md)"
    )
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when the file is out of date")
    args = parser.parse_args(argv)
    out: Path = args.out
    text = render()
    if args.check:
        current = out.read_text(encoding="utf-8") if out.is_file() else ""
        if current != text:
            print(f"{out} is out of date: python -m compare.config_doc", file=sys.stderr)
            return 1
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
