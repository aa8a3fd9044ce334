"""The argument parser of every ``python -m`` tool and script: a usage error is one line and exit 2.

:class:`ArgumentParser` is :class:`argparse.ArgumentParser` with three differences:

* a usage error prints one line, ``error: MESSAGE`` (as the ``tpik-compare`` CLI does), and
  exits with status 2 (no usage block, no traceback);
* an unknown option is reported as such even when a required argument is missing too;
* ``--help`` shows each option's default (unless its help already names one, or the default is
  ``None`` or ``False``).

The ``type=`` converters :func:`existing_dir`, :func:`existing_file`, :func:`positive_int`,
:func:`positive_float`, :func:`non_negative_float`, :func:`fraction`, :func:`output_path` and
:func:`output_dir` reject a bad value while the arguments are
parsed, before any work starts.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

EXIT_USAGE = 2
"""Exit status of a usage error (argparse's and the ``tpik-compare`` CLI's)."""

_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+(e[+-]?\d+)?$")


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keep the description's line breaks; add ``(default: X)`` where the help names none."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if default is None or default is False or default is argparse.SUPPRESS or "default" in text:
            return text
        if not action.option_strings and action.nargs not in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return text
        return f"{text} (default: %(default)s)"


class ArgumentParser(argparse.ArgumentParser):
    """An argument parser whose usage error is one line on stderr and exit status 2."""

    def __init__(self, prog: str, description: str, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(prog=prog, description=description, **kwargs)

    def error(self, message: str) -> NoReturn:
        """Print ``error: MESSAGE`` (one line) and exit with status 2."""
        line = " ".join(message.split())
        self.exit(EXIT_USAGE, f"error: {line}\n")

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        """Parse ``args`` (default ``sys.argv[1:]``); an unknown option is the first error reported."""
        given = list(sys.argv[1:] if args is None else args)
        unknown = self._unknown_options(given)
        if unknown:
            self.error(f"unrecognized arguments: {' '.join(unknown)}")
        return super().parse_args(given, namespace)

    def _unknown_options(self, args: list[str]) -> list[str]:
        known = self._option_string_actions
        out = []
        for arg in args:
            if arg == "--":
                break
            if not arg.startswith("-") or arg == "-" or _NUMBER.match(arg):
                continue
            name = arg.split("=", 1)[0]
            if name in known or (not arg.startswith("--") and arg[:2] in known):
                continue
            if arg.startswith("--") and self.allow_abbrev and any(k.startswith(name) for k in known):
                continue
            out.append(arg)
        return out


def existing_dir(text: str) -> Path:
    """``type=`` converter: a path that is an existing directory."""
    path = Path(text)
    if not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: no such directory")
    return path


def existing_file(text: str) -> Path:
    """``type=`` converter: a path that is an existing file."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    return path


def positive_int(text: str) -> int:
    """``type=`` converter: an integer ≥ 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got '{text}'") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 1, got {value}")
    return value


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got '{text}'")
    return value


def positive_float(text: str) -> float:
    """``type=`` converter: a finite number > 0."""
    value = _float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text}")
    return value


def non_negative_float(text: str) -> float:
    """``type=`` converter: a finite number ≥ 0."""
    value = _float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number ≥ 0, got {text}")
    return value


def fraction(text: str) -> float:
    """``type=`` converter: a number in [0, 1]."""
    value = _float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text}")
    return value


def output_path(text: str) -> Path:
    """``type=`` converter: a file to write; refused when it is a directory."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, expected a file")
    return path


def output_dir(text: str) -> Path:
    """``type=`` converter: a directory to write into (created later); refused when it is a file."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a directory")
    return path


__all__ = [
    "EXIT_USAGE",
    "ArgumentParser",
    "existing_dir",
    "existing_file",
    "fraction",
    "non_negative_float",
    "output_dir",
    "output_path",
    "positive_float",
    "positive_int",
]
