"""build_config: stage configs from untyped session.json values, every error naming the key."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pytest

from pipeline.runner.registry import get_specs
from pipeline.schema.config_types import build_config, check_field_types


@dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    order: int = 3


@dataclass(frozen=True)
class Outer:
    n: int = 2
    scale: float = 0.5
    flag: bool = False
    label: str = "a"
    mode: Literal["fast", "exact"] = "fast"
    path: str | None = None
    pair: tuple[float, float] = (0.1, 0.2)
    names: tuple[str, ...] = ()
    offsets: dict[str, float] = field(default_factory=dict)
    inner: Inner = field(default_factory=Inner)

    def __post_init__(self) -> None:
        if self.n < 0:
            raise ValueError(f"Outer.n must be >= 0, got {self.n}")


def test_values_of_the_right_type_build_the_config() -> None:
    cfg = build_config(
        Outer,
        {"n": 4, "scale": 2, "flag": True, "mode": "exact", "path": "/x", "pair": [1, 2.5],
         "names": ["l", "r"], "offsets": {"cam1": 0.5}, "inner": {"order": 5}},
        "stage_config.x",
    )  # fmt: skip
    assert cfg == Outer(n=4, scale=2, flag=True, mode="exact", path="/x", pair=(1, 2.5), names=("l", "r"),
                        offsets={"cam1": 0.5}, inner=Inner(order=5))  # fmt: skip
    assert isinstance(cfg.pair, tuple) and isinstance(cfg.inner, Inner)  # JSON lists become the hinted tuple
    assert build_config(Outer, {"n": np.int64(3), "scale": np.float32(0.25)}, "x").n == 3
    assert build_config(Outer, {}, "x") == Outer()


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"n": "3"}, r"stage_config\.x\.n must be int, got '3' \(str\)"),
        ({"n": 2.0}, r"stage_config\.x\.n must be int, got 2\.0 \(float\)"),
        ({"n": True}, r"stage_config\.x\.n must be int, got True \(bool\)"),
        ({"scale": "0.5"}, r"stage_config\.x\.scale must be float, got '0\.5' \(str\)"),
        ({"scale": None}, r"stage_config\.x\.scale must be float, got None"),
        ({"flag": 1}, r"stage_config\.x\.flag must be bool, got 1 \(int\)"),
        ({"label": 7}, r"stage_config\.x\.label must be str, got 7 \(int\)"),
        ({"mode": "slow"}, r"stage_config\.x\.mode must be one of \['fast', 'exact'\], got 'slow'"),
        ({"path": 3}, r"stage_config\.x\.path must be str or null, got 3 \(int\)"),
        ({"pair": 0.1}, r"stage_config\.x\.pair must be a list, got 0\.1 \(float\)"),
        ({"pair": [0.1, 0.2, 0.3]}, r"stage_config\.x\.pair must be a list of 2 values, got 3"),
        ({"pair": [0.1, "stiff"]}, r"stage_config\.x\.pair\[1\] must be float, got 'stiff' \(str\)"),
        ({"names": ["l", 2]}, r"stage_config\.x\.names\[1\] must be str, got 2 \(int\)"),
        ({"offsets": [1]}, r"stage_config\.x\.offsets must be an object, got \[1\]"),
        ({"offsets": {"cam1": "late"}}, r"stage_config\.x\.offsets\['cam1'\] must be float, got 'late'"),
        ({"inner": 3}, r"stage_config\.x\.inner must be an object of Inner settings, got 3 \(int\)"),
        ({"inner": {"order": 1.5}}, r"stage_config\.x\.inner\.order must be int, got 1\.5 \(float\)"),
        ({"inner": {"gian": 2.0}}, r"stage_config\.x\.inner has unknown keys \['gian'\]; known: \['gain', 'order'\]"),
        ({"nn": 1}, r"stage_config\.x has unknown keys \['nn'\]"),
        ({"n": -1}, r"stage_config\.x: Outer\.n must be >= 0, got -1"),  # the dataclass's own range check
    ],
)
def test_a_wrong_value_is_refused_with_its_key_path(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        build_config(Outer, values, "stage_config.x")


def test_a_non_object_stage_config_is_refused() -> None:
    with pytest.raises(ValueError, match=r"stage_config\.x must be an object of Outer settings, got \[1, 2\]"):
        build_config(Outer, [1, 2], "stage_config.x")  # type: ignore[arg-type]


def test_check_field_types_names_the_class_and_field() -> None:
    check_field_types(Outer())
    with pytest.raises(ValueError, match=r"Outer\.label must be str, got 1 \(int\)"):
        check_field_types(Outer(label=1))  # type: ignore[arg-type]


@pytest.mark.parametrize("stage", list(get_specs()))
def test_every_stage_config_survives_a_json_round_trip(stage: str) -> None:
    """Every field hint of every real stage config accepts its own default as session.json
    would hold it (tuples as lists, nested configs as objects), and rebuilds the same config;
    a hint that the checker does not understand, or a default of the wrong type, fails here."""
    cls = get_specs()[stage].config_cls
    default = cls()
    as_json = json.loads(json.dumps(dataclasses.asdict(default)))
    assert build_config(cls, as_json, f"stage_config.{stage}") == default
    fields = [f.name for f in dataclasses.fields(cls)]
    assert fields, stage
    # And one wrong type per stage is caught before the dataclass sees it.
    with pytest.raises(ValueError, match=rf"stage_config\.{stage}\.{fields[0]} must be"):
        build_config(cls, {fields[0]: object()}, f"stage_config.{stage}")
