"""Typed recipes: frozen dataclasses built from YAML with the types checked.

`build_dataclass(cls, doc, key)` turns nested plain data (YAML, JSON, `--set` overrides) into
nested frozen dataclasses, coercing and checking each field against its annotation; fields the
document leaves out take their defaults (a dict-valued field is replaced, not merged); an
unknown key or a wrong type is an `InputError` naming the dotted key. `load_recipe` reads a
YAML file and applies `KEY=VALUE` overrides. Used by the synth and train recipes.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from pathlib import Path
from typing import Any

import yaml

from dream.errors import InputError

# YAML 1.1 (PyYAML) reads an exponent without a decimal point, such as 1e-3, as a string
_DECIMAL = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")

T = typing.TypeVar("T")


def plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """`value` (from YAML) as type `tp`, or an InputError naming `key`."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(tp)
        if value is None and type(None) in options:
            return None
        errors = []
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(value, option, key)
            except InputError as exc:
                errors.append(exc)
        raise errors[-1] if len(errors) == 1 else InputError(
            f"config {key}: expected {' or '.join(_type_name(o) for o in options)}, got "
            f"{value!r}")
    if dataclasses.is_dataclass(tp):
        return build_dataclass(tp, value, key)
    if origin is dict:
        key_type, value_type = typing.get_args(tp)
        if not isinstance(value, dict):
            raise InputError(f"config {key}: expected a mapping, got {value!r}")
        return {_coerce(k, key_type, f"{key}") : _coerce(v, value_type, f"{key}.{k}")
                for k, v in value.items()}
    if origin is tuple:
        args = typing.get_args(tp)
        if isinstance(value, (str, int, float)) and len(args) == 2 and args[1] is Ellipsis:
            value = [value]  # `--set data.train=DIR`: one folder
        if not isinstance(value, (list, tuple)):
            raise InputError(f"config {key}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise InputError(f"config {key}: expected {len(args)} values, got {value!r}")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args,
                                                                                 strict=True)))
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str) and _DECIMAL.fullmatch(value.strip()):
            return float(value)
    elif tp is str:
        if isinstance(value, (str, Path)):
            return str(value)
    else:
        raise InputError(f"config {key}: unsupported field type {tp}")
    raise InputError(f"config {key}: expected {_type_name(tp)}, got {value!r}",
                     fix="correct the recipe YAML or the --set override")


def build_dataclass(cls: type, doc: Any, key: str) -> Any:
    if not isinstance(doc, dict):
        raise InputError(f"config {key or 'file'}: expected a mapping of keys, got {doc!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for name in doc:
        if name not in names:
            where = f"{key}.{name}" if key else str(name)
            valid = ", ".join(f"{key}.{n}" if key else n for n in names)
            raise InputError(f"unknown config key '{where}'", fix=f"use one of: {valid}")
    kwargs = {name: _coerce(doc[name], hints[name], f"{key}.{name}" if key else name)
              for name in names if name in doc}
    return cls(**kwargs)


def merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """Deep-merge `update` into a copy of `base` (unknown keys are caught when building)."""
    out = dict(base)
    for name, value in update.items():
        if isinstance(out.get(name), dict) and isinstance(value, dict):
            out[name] = merge(out[name], value)
        else:
            out[name] = value
    return out


def parse_override(text: str) -> dict[str, Any]:
    """'a.b.c=value' -> {'a': {'b': {'c': value}}}, the value parsed as YAML."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise InputError(f"override '{text}' is not KEY=VALUE",
                         fix="write e.g. --set trainer.max_epochs=3")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise InputError(f"override '{text}': the value is not valid YAML ({exc})") from None
    doc: dict[str, Any] = value
    for part in reversed(key.split(".")):
        doc = {part: doc}
    return doc


def load_recipe(cls: type[T], path: str | Path | None, overrides: typing.Sequence[str] = (),
                example: str = "a YAML recipe") -> T:
    """The recipe at `path` (YAML; None: the defaults of `cls`) with `KEY=VALUE` overrides."""
    doc: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot read the config ({exc.strerror or exc})", path,
                             f"give the path of {example}") from None
        except UnicodeDecodeError:
            raise InputError("the config is not UTF-8 text", path,
                             f"give the path of {example}") from None
        fix = f"correct the YAML syntax, or give the path of {example}"
        try:
            doc = yaml.safe_load(text) or {}
        except yaml.YAMLError as exc:
            raise InputError(f"the config is not valid YAML ({str(exc).splitlines()[0]})",
                             path, fix) from None
        if not isinstance(doc, dict):
            raise InputError("the config must be a mapping of sections", path, fix)
    try:
        for text in overrides:
            doc = merge(doc, parse_override(text))
        return build_dataclass(cls, doc, "")
    except InputError as exc:
        if path is None or exc.path is not None:
            raise
        raise InputError(exc.problem, path, exc.fix) from None


def recipe_from_dict(cls: type[T], doc: dict[str, Any], base: Any = None) -> T:
    """A recipe from a (partial) nested dict over `base` (default: the defaults of `cls`)."""
    if not isinstance(doc, dict):
        raise InputError(f"config: expected a mapping of sections, got {doc!r}")
    if base is not None:
        doc = merge(plain(dataclasses.asdict(base)), doc)
    return build_dataclass(cls, doc, "")
