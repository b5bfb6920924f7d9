"""The typed config loader: conversion from the type hints, ranges, sources in errors, dumps."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

import pytest

from chpf.config_schema import Invalid, Section, load, parse_sets, setting, to_dict, to_yaml
from chpf.errors import ConfigError


@dataclass
class Inner(Section):
    count: int = setting(3, ge=1)
    share: float = setting(0.5, ge=0.0, le=1.0)
    band: tuple[float, float] = setting((1.0, 2.0), ordered=True)
    steps: tuple[float, ...] = (1.0,)
    mode: Literal["a", "b"] = "a"
    path: str | None = None
    on: bool = False
    names: list[str] = field(default_factory=lambda: ["x"])

    def check(self) -> None:
        if self.mode == "b" and self.count > 5:
            raise Invalid("count", "must be <= 5 in mode b")


@dataclass
class Outer(Section):
    inner: Inner = field(default_factory=Inner)
    other: Inner = field(default_factory=Inner)


def test_values_are_converted_from_the_type_hints():
    cfg = load(
        Outer,
        data={"inner": {"count": 4.0, "share": 1, "band": [1, 3], "steps": [0.5, 1], "on": True}},
    )
    inner = cfg.inner
    assert inner.count == 4 and isinstance(inner.count, int)
    assert inner.share == 1.0 and isinstance(inner.share, float)
    assert inner.band == (1.0, 3.0) and inner.steps == (0.5, 1.0) and inner.on is True
    assert cfg.other == Inner()


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"inner": {"count": 2.5}}, "inner.count: expected an integer, got 2.5"),
        ({"inner": {"count": True}}, "inner.count: expected a number"),
        ({"inner": {"count": "3"}}, "inner.count: expected a number"),
        ({"inner": {"count": 0}}, "inner.count: 0 is out of range [1, inf)"),
        ({"inner": {"share": 1.5}}, "inner.share: 1.5 is out of range [0.0, 1.0]"),
        ({"inner": {"share": float("nan")}}, "inner.share: expected a finite number"),
        ({"inner": {"band": [3, 1]}}, "inner.band: min 3.0 > max 1.0"),
        ({"inner": {"band": [1, 2, 3]}}, "inner.band: expected 2 values"),
        ({"inner": {"mode": "c"}}, "inner.mode: expected one of a, b, got 'c'"),
        ({"inner": {"on": "yes"}}, "inner.on: expected true or false"),
        ({"inner": {"path": 3}}, "inner.path: expected a string"),
        ({"inner": {"names": "x"}}, "inner.names: expected a list"),
        ({"inner": {"mode": "b", "count": 6}}, "inner.count: must be <= 5 in mode b"),
        ({"inner": {"bogus": 1}}, "unknown key inner.bogus (known: count, share"),
        ({"bogus": {}}, "unknown section 'bogus' (known: inner, other)"),
        ({"inner": 3}, "section 'inner' must be a mapping"),
    ],
)
def test_refusals_name_the_source_and_the_dotted_key(data, needle):
    with pytest.raises(ConfigError) as err:
        load(Outer, data=data, where="my.yaml")
    msg = str(err.value)
    assert msg.startswith("my.yaml: ") and needle in msg and "\n" not in msg


def test_file_then_sets_and_errors_name_their_source(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("inner:\n  count: 4\nother: null\n")
    cfg = load(Outer, path=p, sets=["inner.share=0.25", "other.band=[0, 5]"])
    assert cfg.inner.count == 4 and cfg.inner.share == 0.25 and cfg.other.band == (0.0, 5.0)
    with pytest.raises(ConfigError, match=r"^--set: inner\.share: 2\.0 is out of range"):
        load(Outer, path=p, sets=["inner.share=2"])
    p.write_text("inner:\n  count: 0\n")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(p))}: inner\.count"):
        load(Outer, path=p)
    p.write_text("inner: [1, 2\n")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(p))}: not valid YAML at line"):
        load(Outer, path=p)
    with pytest.raises(ConfigError, match=r"expected section\.key=value"):
        parse_sets(["inner.count"])


def test_a_config_built_in_code_is_checked_too():
    with pytest.raises(ConfigError, match="share"):
        Inner(share=2.0)


def test_dump_reads_back():
    cfg = load(Outer, sets=["inner.steps=[0.2, 1.0]", "other.path=/tmp/x"])
    d = to_dict(cfg)
    assert d["inner"]["steps"] == [0.2, 1.0] and d["other"]["path"] == "/tmp/x"
    assert load(Outer, data=d) == cfg
    assert "steps:\n  - 0.2\n" in to_yaml(cfg)
