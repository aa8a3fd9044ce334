"""What identifies the scenario a result belongs to: the configuration without its methods.

Two runs are of *the same scenario and config* when every key of the configuration but
``[methods]`` is equal (the seed included): their results may live in one directory, one method
next to the other. The fingerprint is the configuration flattened to dotted keys
(``scenario.duration_s``, ``levels[0].tasks[1].type``, ...), so a difference can be named key by
key; the hash is the SHA-256 of its canonical JSON.

Per-method settings (``[methods.settings.<name>]``) belong to that method only: they are recorded
with the method (:func:`method_settings`), not in the hash.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from typing import Any

from compare.config import Config

EXCLUDED = frozenset({"methods"})
"""Top-level sections left out of the fingerprint."""
HASHED_WHEN_SET = frozenset({"prediction"})
"""Sections that enter the hash only when they differ from their defaults: at their defaults they
change nothing, so results written before the section existed stay results of the same config."""


def _plain(value: Any) -> Any:
    """JSON-safe and canonical: tuples as lists, non-finite floats as strings."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # "inf", "-inf", "nan"
    return value


def _flatten(value: Any, prefix: str, out: dict[str, Any]) -> None:
    if isinstance(value, dict) and value:
        for k in sorted(value):
            _flatten(value[k], f"{prefix}.{k}" if prefix else str(k), out)
    elif isinstance(value, list) and value and any(isinstance(v, dict) for v in value):
        for i, v in enumerate(value):
            _flatten(v, f"{prefix}[{i}]", out)
        out[f"{prefix}.length"] = len(value)
    else:
        out[prefix] = value


def config_fingerprint(config: Config) -> dict[str, Any]:
    """The configuration without ``[methods]``, flattened to ``{dotted key: JSON value}``."""
    data = config.model_dump(mode="python")
    out: dict[str, Any] = {}
    _flatten(_plain({k: v for k, v in data.items() if k not in EXCLUDED}), "", out)
    return out


@functools.cache
def _section_defaults(section: str) -> dict[str, Any]:
    """The fingerprint keys of ``section`` at its defaults (computed once; callers only compare)."""
    out: dict[str, Any] = {}
    default = Config.model_fields[section].default_factory()  # type: ignore[misc]
    _flatten(_plain(default.model_dump(mode="python")), section, out)
    return out


def fingerprint_hash(fingerprint: dict[str, Any]) -> str:
    """SHA-256 (hex) of the canonical JSON of a :func:`config_fingerprint`.

    A section of :data:`HASHED_WHEN_SET` whose keys all hold their defaults is left out.
    """
    for section in HASHED_WHEN_SET:
        keys = {k: v for k, v in fingerprint.items() if k.startswith(f"{section}.")}
        if keys == _section_defaults(section):
            fingerprint = {k: v for k, v in fingerprint.items() if k not in keys}
    text = json.dumps(fingerprint, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def config_hash(config: Config) -> str:
    """:func:`fingerprint_hash` of :func:`config_fingerprint` (the scenario's identity)."""
    return fingerprint_hash(config_fingerprint(config))


def method_settings(config: Config, method: str) -> dict[str, Any]:
    """The ``[methods.settings.<method>]`` table, JSON-safe (empty when there is none)."""
    plain = _plain(dict(config.methods.settings.get(method) or {}))
    return plain if isinstance(plain, dict) else {}


def describe_differences(old: dict[str, Any], new: dict[str, Any], limit: int = 3) -> str:
    """The keys whose values differ, as ``key old → new`` (at most ``limit``, then ``and N more``)."""
    differ = (k for k in set(old) | set(new) if old.get(k, "<unset>") != new.get(k, "<unset>"))
    keys = sorted(differ, key=lambda k: (not k.startswith("scenario."), k))  # the scenario's own keys first
    parts = [f"{k} {json.dumps(old.get(k, '<unset>'))} → {json.dumps(new.get(k, '<unset>'))}" for k in keys[:limit]]
    if len(keys) > limit:
        parts.append(f"and {len(keys) - limit} more")
    return ", ".join(parts)
