"""The argparse of `agent-envs`: one error path, subcommands, and options made from dataclasses.

- `ArgumentParser`: argparse whose `error` raises `UsageError` (printed by `cli.main` as one
  line, exit code 2) instead of printing the usage block and exiting;
- `Subcommand`: a help line, an options dataclass named ``"module:Class"`` (imported only when
  the subcommand is chosen) and ``run(config) -> int``;
- `add_dataclass_arguments`: one option per field of an options dataclass (name, type, default
  and --help from the field and its `config.option_field` metadata), and
  `config_from_namespace`, the namespace back to the dataclass (which validates its values).

Standard library only, so that building a light subcommand's parser imports no torch.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any


class UsageError(Exception):
    """A command-line error: printed as one line, exit code 2."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with the project's one error path: an error is a `UsageError` (one line).

    argparse's own `error` prints the usage block and exits; here the message is raised so
    that `main` prints it as the one line ``agent-envs COMMAND: error: ...``. Subparsers are
    of this class too (argparse creates them with the parent's class).
    """

    def error(self, message: str):  # type: ignore[override]
        raise UsageError(f"{self.prog}: error: {message} (see {self.prog} --help)")


@dataclass(frozen=True)
class Subcommand:
    """One `agent-envs` subcommand: its help line, its options dataclass and what it runs.

    The options are generated from the dataclass `config` (``"module:Class"``, imported only
    when the subcommand is chosen) by `add_dataclass_arguments`; `run` is called with the
    dataclass built from them (which validates them), or, with `given_only`, with the dict of
    the options given on the command line (`train`: options left out come from a resumed run).
    """

    help: str
    config: str
    run: Callable[[Any], int]
    description: str = ""
    given_only: bool = False

    def config_class(self) -> type:
        """The options dataclass (its module is imported here)."""
        module, name = self.config.split(":")
        return getattr(importlib.import_module(module), name)

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        """One option per field of the options dataclass."""
        if self.description:
            parser.description = self.description
        add_dataclass_arguments(parser, self.config_class(), suppress_defaults=self.given_only)

    def options(self, args: argparse.Namespace) -> Any:
        """What `run` is called with: the options dataclass, or the dict of given options."""
        cls = self.config_class()
        if self.given_only:
            names = {f.name for f in dataclasses.fields(cls)}
            return {k: v for k, v in vars(args).items() if k in names}
        return config_from_namespace(cls, args)


# ------------------------------------------------------------------ options from dataclasses

#: Field metadata read by `add_dataclass_arguments` only (every other key goes to argparse):
#: ``help``: the --help text; ``flags``: the option strings instead of ``--field-name`` (an
#: alias such as ``("--policy", "-p")``, or ``("--no-progress",)`` with
#: ``action="store_false"``); ``positional``: a positional argument named like the field.
_OWN_METADATA = ("help", "flags", "positional")
#: Element types of the fields, by annotation.
_TYPES: dict[str, type] = {"int": int, "float": float, "str": str, "Path": Path}


def _annotation(f: dataclasses.Field) -> tuple[str, bool]:
    """(element type name, list-valued) of a field: ``tuple[float, ...] | None`` -> float, True."""
    text = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    text = text.removesuffix(" | None")
    match = re.fullmatch(r"(?:tuple|list)\[(\w+)(?:, \.\.\.)?\]", text)
    return (match.group(1), True) if match else (text, False)


def _shown(default: Any) -> str:
    """A default as --help shows it: dicts as JSON, lists as their items."""
    if isinstance(default, dict):
        return json.dumps(default)
    if isinstance(default, (tuple, list)):
        return " ".join(map(str, default))
    return str(default)


def _argument_kwargs(f: dataclasses.Field, suppress_defaults: bool) -> dict[str, Any]:
    """argparse keyword arguments of a field (its metadata's argparse keys added last)."""
    meta = {k: v for k, v in f.metadata.items() if k not in _OWN_METADATA}
    help_text = f.metadata.get("help", "")
    if f.default is not dataclasses.MISSING:
        default = f.default
    elif f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        default = dataclasses.MISSING
    kwargs: dict[str, Any] = {"dest": f.name, "help": help_text}
    if default is dataclasses.MISSING:
        kwargs["required"] = True
    else:
        kwargs["default"] = argparse.SUPPRESS if suppress_defaults else default
        if "default" not in help_text.lower() and "action" not in meta:
            kwargs["help"] = f"{help_text} (default: {_shown(default)})"
    name, many = _annotation(f)
    if name == "bool":
        if "action" not in meta:
            kwargs["action"] = argparse.BooleanOptionalAction
    elif name == "dict":
        kwargs.update(metavar="JSON", type=str)
    else:
        kwargs["type"] = _TYPES.get(name, str)
        if many and "action" not in meta:
            kwargs["nargs"] = "+"
    kwargs.update(meta)
    return kwargs


def add_dataclass_arguments(
    parser: argparse.ArgumentParser,
    cls: type,
    *,
    exclude: tuple[str, ...] = (),
    suppress_defaults: bool = False,
) -> None:
    """Add one `--field-name` option per dataclass field, with the field's metadata help.

    By the field's annotation: booleans accept `--flag/--no-flag` (or, with ``action`` in the
    metadata, are a `store_true`/`store_false` flag); dict fields take a JSON object (parsed
    and checked by the dataclass); ``int``, ``float``, ``Path`` and ``str`` fields are typed
    as annotated; ``tuple[X, ...]`` / ``list[X]`` fields take one or more X (``nargs="+"``); a
    field without a default is a required option. Metadata keys other than ``help``, ``flags``
    and ``positional`` (see `_OWN_METADATA`) are passed to argparse (``choices``, ``nargs``,
    ``type``, ``action``, ``metavar``). With `suppress_defaults`, options left out do not
    appear in the namespace (so a caller can tell "not given" from "given the default").
    """
    for f in dataclasses.fields(cls):
        if f.name in exclude or not f.init:
            continue
        kwargs = _argument_kwargs(f, suppress_defaults)
        if f.metadata.get("positional"):
            del kwargs["dest"]
            kwargs.pop("required", None)
            parser.add_argument(f.name, **kwargs)
        else:
            flags = f.metadata.get("flags", ("--" + f.name.replace("_", "-"),))
            parser.add_argument(*flags, **kwargs)


def config_from_namespace(cls: type, args: argparse.Namespace, **overrides: Any) -> Any:
    """Build a dataclass from the namespace filled by `add_dataclass_arguments`.

    Lists given to a tuple-valued field become tuples; the dataclass validates the values.
    """
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init or f.name not in vars(args):
            continue
        value = getattr(args, f.name)
        if isinstance(value, list) and _annotation(f)[1]:
            value = tuple(value)
        values[f.name] = value
    values.update(overrides)
    return cls(**values)
