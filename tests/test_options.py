"""Options declared once: the mechanism, the registries, and docs generated from them."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from pathlib import Path

import pytest

from odofuse import declarations
from odofuse.config import RunConfig
from odofuse.errors import ConfigError
from odofuse.options import describe, from_mapping, markdown_table, option, render_docs

ROOT = Path(__file__).resolve().parent.parent


def _halve(value, key, source):
    if value not in ("half", "full"):
        raise ConfigError(f"expected half or full, got {value!r}", source, key)
    return 0.5 if value == "half" else 1.0


@dataclass(frozen=True)
class Inner:
    rate: float = option(1.0, unit="Hz", doc="sample rate", minimum=0, exclusive_minimum=True)


@dataclass(frozen=True)
class Demo:
    """A test block."""

    flag: bool = option(False, unit="-", doc="a flag")
    count: int = option(3, unit="-", doc="a count", minimum=1)
    gain: float = option(0.5, unit="-", doc="a fraction", minimum=0, maximum=1)
    mode: str = option("a", unit="-", doc="a mode", choices=("a", "b"))
    xy: tuple[float, float] = option((0.0, 0.0), unit="m", doc="a point")
    many: tuple[float, ...] = option((), unit="m", doc="any number of lengths", minimum=0)
    maybe: float | None = option(None, unit="s", doc="optional")
    either: float | tuple[float, ...] = option(1.0, unit="-", doc="one or per input")
    table: dict[str, float] = option(
        dataclasses.MISSING, unit="-", doc="name -> value", default_factory=dict
    )
    inner: Inner = option(default_factory=Inner, unit="-", doc="a nested block")
    scale: float = option(1.0, unit="-", doc="half or full", parse=_halve)


def test_types_defaults_and_nesting():
    d = from_mapping(Demo, {}, "demo", "f.yaml")
    assert d == Demo() and d.inner.rate == 1.0
    d = from_mapping(
        Demo,
        {
            "flag": True,
            "count": 4,
            "gain": 1,
            "mode": "b",
            "xy": [1, 2],
            "many": [1.0, 2.0, 3.0],
            "maybe": 2,
            "either": [0.1, 0.2],
            "table": {"a": 1},
            "inner": {"rate": 10},
            "scale": "half",
        },
        "demo",
        "f.yaml",
    )
    assert (d.flag, d.count, d.gain, d.mode, d.xy, d.many) == (
        True,
        4,
        1.0,
        "b",
        (1.0, 2.0),
        (1, 2, 3),
    )
    assert d.maybe == 2.0 and d.either == (0.1, 0.2) and dict(d.table) == {"a": 1.0}
    assert d.inner == Inner(rate=10.0) and d.scale == 0.5
    assert isinstance(d.gain, float) and isinstance(d.xy, tuple)
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.count = 5  # type: ignore[misc]


@pytest.mark.parametrize(
    ("block", "key", "match"),
    [
        ({"colour": 1}, "demo.colour", r"unknown key \(allowed: flag, count, gain, mode, xy"),
        ({"flag": "yes"}, "demo.flag", "true or false"),
        ({"count": 1.5}, "demo.count", "integer"),
        ({"count": True}, "demo.count", "integer"),
        ({"count": 0}, "demo.count", ">= 1"),
        ({"gain": 2.0}, "demo.gain", r"in \[0, 1\]"),
        ({"gain": "x"}, "demo.gain", "number"),
        ({"gain": float("nan")}, "demo.gain", "finite"),
        ({"mode": "c"}, "demo.mode", "one of a, b"),
        ({"xy": [1.0]}, "demo.xy", "2 elements"),
        ({"xy": [1.0, "y"]}, "demo.xy[1]", "number"),
        ({"many": [1.0, -1.0]}, "demo.many[1]", "not negative"),
        ({"maybe": "soon"}, "demo.maybe", "a number or null"),
        ({"table": {"a": "b"}}, "demo.table.a", "number"),
        ({"inner": {"rate": 0}}, "demo.inner.rate", "positive"),
        ({"inner": {"rte": 1}}, "demo.inner.rte", "unknown key"),
        ({"inner": 3}, "demo.inner", "mapping"),
        ({"scale": "double"}, "demo.scale", "half or full"),
    ],
)
def test_errors_name_the_dotted_key_and_the_file(block, key, match):
    with pytest.raises(ConfigError, match=match) as info:
        from_mapping(Demo, block, "demo", "run.yaml")
    assert info.value.key == key and info.value.file == "run.yaml"
    assert str(info.value).startswith(f"run.yaml, key '{key}': ")


def test_required_key_and_cross_field_check():
    @dataclass(frozen=True)
    class Needs:
        lo: float = option(unit="m", doc="required")
        hi: float = option(2.0, unit="m", doc="above lo")

        def check(self):
            if self.hi <= self.lo:
                raise ConfigError("must be above lo", key="hi")

    with pytest.raises(ConfigError, match="missing required value") as info:
        from_mapping(Needs, {}, "b", "f.yaml")
    assert info.value.key == "b.lo"
    with pytest.raises(ConfigError, match="above lo") as info:
        from_mapping(Needs, {"lo": 3.0}, "b", "f.yaml")
    assert info.value.key == "b.hi" and info.value.file == "f.yaml"


def test_a_new_option_is_added_in_one_place_and_shows_up_in_validation_and_docs(monkeypatch):
    # One new field on one class: validation, defaults, the docs table and the run config
    # all pick it up; nothing else is edited.
    @dataclass(frozen=True)
    class EkfWithNew(declarations.EkfOptions):
        """``options.ekf``: the extended Kalman filter."""

        innovation_cap: float = option(
            5.0, unit="sigma", doc="largest accepted innovation", minimum=0, exclusive_minimum=True
        )

    monkeypatch.setitem(declarations.ESTIMATOR_OPTIONS, "ekf", EkfWithNew)
    cfg = RunConfig(
        log="x",
        robot={"drive": "increments"},
        estimator="ekf",
        options={"ekf": {"innovation_cap": 3}},
        source="run.yaml",
    )
    assert cfg.estimator_options().innovation_cap == 3.0
    assert cfg.estimator_options().late_window == 0.5
    with pytest.raises(ConfigError) as info:
        RunConfig(
            log="x",
            robot={"drive": "increments"},
            options={"ekf": {"innovation_cap": -1}},
            source="run.yaml",
        )
    assert info.value.key == "options.ekf.innovation_cap"
    table = declarations.doc_tables()["ekf"]
    assert (
        "| `options.ekf.innovation_cap` | float, > 0 | sigma | `5` | largest accepted innovation |"
        in table
    )
    assert "innovation_cap" not in (ROOT / "docs" / "filters.md").read_text()
    fresh = render_docs((ROOT / "docs" / "filters.md").read_text(), declarations.doc_tables())
    assert "options.ekf.innovation_cap" in fresh


def test_every_registered_field_has_a_unit_and_a_meaning():
    classes = {cls for cls, _ in declarations.catalogue().values()}
    assert len(classes) >= 13
    for cls in classes:
        for f in dataclasses.fields(cls):
            assert f.metadata.get("unit"), (cls.__name__, f.name)
            assert f.metadata.get("doc"), (cls.__name__, f.name)
        assert cls.__dataclass_params__.frozen, cls.__name__
        typing.get_type_hints(cls)  # every annotation resolves
        assert describe(cls)


def test_registries_cover_the_estimators_and_the_sensor_kinds():
    from odofuse.estimators import ESTIMATORS
    from odofuse.measurements import MODELS

    assert set(declarations.ESTIMATOR_OPTIONS) == set(ESTIMATORS)
    assert set(declarations.SENSOR_OPTIONS) == set(MODELS)
    assert set(declarations.STREAM_DEFAULTS.values()) <= set(MODELS)


def test_docs_tables_match_the_declarations():
    tables = declarations.doc_tables()
    for rel in declarations.DOC_FILES:
        text = (ROOT / rel).read_text(encoding="utf-8")
        assert render_docs(text, tables) == text, (
            f"{rel}: run python -m odofuse.declarations --write-docs"
        )
    every = "".join((ROOT / rel).read_text() for rel in declarations.DOC_FILES)
    for name in tables:
        assert f"<!-- options:{name} -->" in every, name


def test_markdown_table_rows():
    table = markdown_table(Inner, "x")
    assert table.splitlines()[2] == "| `x.rate` | float, > 0 | Hz | `1` | sample rate |"


def test_plugin_sensor_declares_its_own_options():
    models = pytest.importorskip("odofuse.measurements")

    @dataclass(frozen=True)
    class Sonar(models.CompassHeading):
        @dataclass(frozen=True)
        class Options:
            sigma: float = option(0.2, unit="rad", doc="noise", minimum=0, exclusive_minimum=True)

    import sys
    import types

    mod = types.ModuleType("odofuse_test_sonar")
    mod.Sonar = Sonar
    sys.modules["odofuse_test_sonar"] = mod
    try:
        cfg = RunConfig(
            log="x",
            robot={"drive": "increments"},
            source="run.yaml",
            sensors={"sonar": {"class": "odofuse_test_sonar:Sonar", "gate": 0.9}},
        )
        model = models.measurement_models(cfg)["sonar"]
        assert model.sigma == 0.2 and model.gate == 0.9 and model.name == "sonar"
        with pytest.raises(ConfigError) as info:
            RunConfig(
                log="x",
                robot={"drive": "increments"},
                source="run.yaml",
                sensors={"sonar": {"class": "odofuse_test_sonar:Sonar", "sigam": 1}},
            )
        assert info.value.key == "sensors.sonar.sigam"
    finally:
        del sys.modules["odofuse_test_sonar"]


def test_cli_lists_the_options(capsys):
    from odofuse.cli import main

    assert main(["options", "sensors.gyro"]) == 0
    out = capsys.readouterr().out
    assert "sensors.<stream>.threshold" in out and "rad" in out
    assert main(["options"]) == 0
    assert "particle" in capsys.readouterr().out


def test_unquoted_on_off_in_yaml_select_the_on_off_choices(tmp_path):
    # README and docs/batch.md write `options: {cross_check: {smoother: off}}`; YAML 1.1 reads
    # an unquoted off as false, which was "must be a non-empty string, got False"
    from odofuse.config import load_config

    path = tmp_path / "run.yaml"
    path.write_text(
        "log: builtin:plaza1\nrobot: {drive: increments}\nestimator: ekf\n"
        "options: {cross_check: {smoother: off}, ekf: {compiled: on}}\n"
    )
    options = load_config(path).options
    assert options["cross_check"].smoother == "off"
    assert options["ekf"].compiled == "on"
