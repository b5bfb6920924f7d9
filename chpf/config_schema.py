"""Typed configs: nested dataclasses loaded from YAML, dicts and ``--set section.key=value``.

A config is a dataclass whose fields are plain settings or nested config dataclasses (sections).
Values are converted to the field's type hint (``typing.get_type_hints``: bool, int, float, str,
``Literal[...]``, ``X | None``, ``tuple[float, float]``, ``tuple[float, ...]``, ``list[str]``)
and range-checked from the field's metadata (see ``setting``); a section's ``check()`` holds its
cross-key rules. Every refusal is one ConfigError line naming the source and the dotted key.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union

import yaml

from chpf.errors import ConfigError

T = TypeVar("T")


class Invalid(ConfigError):
    """A refused value of ``key`` (raised by a section; the loader adds source and section)."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


def setting(
    default: Any = dataclasses.MISSING,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    ordered: bool = False,
    factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with a range: ge/gt/le bound the number (or each number of a tuple);
    ordered: a tuple's numbers must not decrease (a [min, max] pair)."""
    meta = {"ge": ge, "gt": gt, "le": le, "ordered": ordered}
    if factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _check_range(key: str, value: Any, meta: Mapping[str, Any]) -> None:
    """Invalid if ``value`` (a number or a tuple/list of numbers) is outside meta's range."""
    if value is None or isinstance(value, (str, bool)):
        return
    numbers = list(value) if isinstance(value, (tuple, list)) else [value]
    ge, gt, le = meta.get("ge"), meta.get("gt"), meta.get("le")
    for v in numbers:
        if not isinstance(v, (int, float)):
            return
        if (
            (ge is not None and v < ge)
            or (gt is not None and v <= gt)
            or (le is not None and v > le)
        ):
            lo = f"[{ge}" if ge is not None else (f"({gt}" if gt is not None else "(-inf")
            hi = f"{le}]" if le is not None else "inf)"
            raise Invalid(key, f"{v!r} is out of range {lo}, {hi}")
    if meta.get("ordered"):
        for a, b in itertools.pairwise(numbers):
            if a > b:
                raise Invalid(key, f"min {a} > max {b}")


@dataclasses.dataclass
class Section:
    """Base of config dataclasses: settings are range-checked on construction, then check().

    A dataclass itself, so that jsonargparse (LightningCLI) reads its subclasses as nested
    groups of keys (``--model.encoder.kernel``) rather than as classes to pick by class_path.
    """

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            _check_range(f.name, getattr(self, f.name), f.metadata)
        self.check()

    def check(self) -> None:
        """Cross-key rules; raise Invalid(key, problem)."""


def _coerce(value: Any, hint: Any, key: str) -> Any:
    """``value`` converted to the type ``hint``; Invalid(key, ...) if it is not one."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        if value is None:
            raise Invalid(key, "must not be null")
        return _coerce(value, inner, key)
    if origin is Literal:
        if value not in args:
            raise Invalid(key, f"expected one of {', '.join(map(str, args))}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise Invalid(key, f"expected a list, got {value!r}")
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise Invalid(key, f"expected {len(args)} values, got {list(value)!r}")
            items = [_coerce(v, a, key) for v, a in zip(value, args, strict=True)]
        else:
            items = [_coerce(v, args[0], key) for v in value]
        return tuple(items) if origin is tuple else items
    if hint is bool:
        if not isinstance(value, bool):
            raise Invalid(key, f"expected true or false, got {value!r}")
        return value
    if hint in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise Invalid(key, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            raise Invalid(key, f"expected a finite number, got {value!r}")
        if hint is int and not float(value).is_integer():
            raise Invalid(key, f"expected an integer, got {value!r}")
        return hint(value)
    if hint is str:
        if not isinstance(value, str):
            raise Invalid(key, f"expected a string, got {value!r}")
        return value
    raise TypeError(f"config type {hint!r} of {key} is not supported")


def _is_section(hint: Any) -> bool:
    return isinstance(hint, type) and dataclasses.is_dataclass(hint)


def _values(obj: Any) -> dict[str, Any]:
    """Field values of a config, sections as nested dicts (tuples kept)."""
    return {
        f.name: _values(v) if dataclasses.is_dataclass(v) else v
        for f in dataclasses.fields(obj)
        for v in [getattr(obj, f.name)]
    }


def _merge(cls: type, values: dict[str, Any], layer: Any, where: str, prefix: str = "") -> None:
    """Update ``values`` in place with the mapping ``layer``, each value converted and checked."""
    if not isinstance(layer, Mapping):
        what = f"section {prefix[:-1]!r}" if prefix else "a config"
        raise ConfigError(f"{where}: {what} must be a mapping, got {type(layer).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for name, raw in layer.items():
        if name not in names:
            if not prefix and all(_is_section(hints[n]) for n in names):
                known = ", ".join(names)
                raise ConfigError(f"{where}: unknown section {name!r} (known: {known})")
            raise ConfigError(f"{where}: unknown key {prefix}{name} (known: {', '.join(names)})")
        if _is_section(hints[name]):
            if raw is not None:
                _merge(hints[name], values[name], raw, where, f"{prefix}{name}.")
            continue
        field = next(f for f in dataclasses.fields(cls) if f.name == name)
        try:
            value = _coerce(raw, hints[name], name)
            _check_range(name, value, field.metadata)
        except Invalid as err:
            raise ConfigError(f"{where}: {prefix}{err}") from None
        values[name] = value


def _build(cls: type[T], values: dict[str, Any], where: str, prefix: str = "") -> T:
    hints = typing.get_type_hints(cls)
    kwargs = {
        k: _build(hints[k], v, where, f"{prefix}{k}.") if _is_section(hints[k]) else v
        for k, v in values.items()
    }
    try:
        return cls(**kwargs)
    except Invalid as err:
        raise ConfigError(f"{where}: {prefix}{err}") from None


def read_yaml(path: str | Path) -> Any:
    """The YAML document of ``path``; ConfigError (one line) if unreadable or invalid."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{p}: cannot read config ({err.strerror})") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as err:
        line = getattr(getattr(err, "problem_mark", None), "line", None)
        at = f" at line {line + 1}" if line is not None else ""
        raise ConfigError(f"{p}: not valid YAML{at}") from None


def parse_sets(sets: Iterable[str]) -> dict[str, Any]:
    """``["a.b=1", "a.c=[1, 2]"]`` -> ``{"a": {"b": 1, "c": [1, 2]}}`` (values parsed as YAML)."""
    out: dict[str, Any] = {}
    for item in sets:
        dotted, eq, raw = item.partition("=")
        if not eq or not dotted.strip():
            raise ConfigError(f"--set {item!r}: expected section.key=value")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"--set {item!r}: value is not valid YAML") from None
        *parents, leaf = dotted.strip().split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {item!r}: {part} is set twice")
        node[leaf] = value
    return out


def load(
    cls: type[T],
    path: str | Path | None = None,
    sets: Iterable[str] = (),
    data: Mapping[str, Any] | None = None,
    base: T | None = None,
    where: str = "config",
    prefix: str = "",
) -> T:
    """``base`` (default: cls()) updated by the YAML file ``path``, then ``data`` (named
    ``where`` in errors), then ``sets`` ("section.key=value"); checked. ConfigError (one line)
    naming the source and the key (``data``'s keys after ``prefix``, e.g. "model.encoder.") on
    unknown keys, wrong types and out-of-range values."""
    values = _values(base if base is not None else cls())
    sources = []
    if path is not None:
        doc = read_yaml(path)
        _merge(cls, values, {} if doc is None else doc, str(path))
        sources.append(str(path))
    if data is not None and (data or not isinstance(data, Mapping)):
        _merge(cls, values, data, where, prefix)
        sources.append(where)
    sets = list(sets)
    if sets:
        _merge(cls, values, parse_sets(sets), "--set")
        sources.append("--set")
    return _build(cls, values, " + ".join(sources) or where, prefix)


def to_dict(cfg: Any) -> dict[str, Any]:
    """Plain dict of a config (tuples as lists): what ``load(cls, data=...)`` reads back."""
    return {
        k: to_dict(v)
        if dataclasses.is_dataclass(v)
        else list(v)
        if isinstance(v, (tuple, list))
        else v
        for k, v in ((f.name, getattr(cfg, f.name)) for f in dataclasses.fields(cfg))
    }


def to_yaml(cfg: Any) -> str:
    """The config as YAML text (sections as mappings, in field order)."""
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
