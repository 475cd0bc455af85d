"""The deployment configuration (TOML): the example configs, validation that names every field
with its unit and range, `config check` / `config show`, the round trip, the daemon reading it,
and the Set_Limits the controller sends at arming."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import uuid
from pathlib import Path

import pytest
from hypothesis import given, settings as hypothesis_settings, strategies as st

from controller.config import ControllerConfig
from controller.io.axis import AxisConfig
from controller.settings.file import (MODEL, SECTIONS, BusSettings, CalibrationSettings, ConfigError, DeployConfig,
                                 DriverSettings, ServiceSettings, WeightsSettings, _build, check_config,
                                 config_from_dict, config_from_toml, config_tables, load_config, to_toml,
                                 toml_string, tomllib, validate_tables, write_config)
from hil.cli import main
from controller.settings.daemon import daemon_settings
from hil.analysis.legacy_config import load_controller_config

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = {"sim": ROOT / "configs" / "sim.toml", "odrive-leg": ROOT / "configs" / "odrive-leg.toml"}


def write(tmp_path: Path, text: str, name: str = "leg.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def check(capsys, path) -> tuple[int, str, str]:
    rc = main(["config", "check", str(path)])
    out = capsys.readouterr()
    return rc, out.out, out.err


# --------------------------------------------------------------------------- the examples
@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_the_example_configs_pass_check(name, capsys):
    rc, out, err = check(capsys, EXAMPLES[name])
    assert rc == 0, err
    assert out.startswith(f"{EXAMPLES[name]}: OK: socketcan ") and out.count("\n") == 1
    if name == "sim":  # the simulation: confirmed, no warning
        assert not err and out.rstrip().endswith("calibration confirmed")
    else:  # a real leg's example values: valid, but not armable until a person confirms them
        assert out.rstrip().endswith("calibration NOT confirmed")
        assert err.startswith(f"WARNING: {EXAMPLES[name]}: calibration not confirmed") and err.count("\n") == 1
        assert "bringup --config" in err and "config confirm" in err


def test_the_sim_example_is_the_simulated_leg_as_hil_runs_it():
    from firmware_sim.leg import LegHardware
    from firmware_sim.odrive_axis import DriverConfig
    from hil.experiments.learn import LearnConfig

    cfg = load_config(EXAMPLES["sim"])
    assert cfg.bus == BusSettings("socketcan", "vcan0", 1_000_000)
    assert cfg.controller.auto_arm is True  # the simulation arms itself, as lockstep runs do
    lockstep = LearnConfig().lockstep().controller
    assert dataclasses.replace(cfg.controller, auto_arm=False) == dataclasses.replace(lockstep, auto_arm=False) \
        == ControllerConfig()
    assert cfg.calibration.confirmed is True and cfg.armable_reason() is None  # the simulation, confirmed
    assert cfg.service.control_socket == "/tmp/elegant-stepping-sim.sock"  # works without root
    hw, driver = LegHardware(), DriverConfig(node_id=0)
    hip, knee = cfg.controller.axis("hip"), cfg.controller.axis("knee")
    assert (hip.node_id, knee.node_id) == (hw.hip_node_id, hw.knee_node_id)
    assert (hip.direction, knee.direction) == (hw.hip_direction, hw.knee_direction)
    assert (hip.zero_offset_rev, knee.zero_offset_rev) == (hw.hip_zero_offset_rev, hw.knee_zero_offset_rev)
    for axis in (hip, knee):
        assert axis.gear_ratio == hw.gear_ratio
        assert axis.current_limit_a == hw.motor.current_limit_a
        assert axis.vel_limit_rev_s == driver.vel_limit_rev_s
    assert cfg.drivers.watchdog_timeout_s == driver.watchdog_timeout_s
    assert cfg.controller.heartbeat_period_s == driver.heartbeat_period_s


def test_the_odrive_example_is_a_real_leg_on_can0():
    cfg = load_config(EXAMPLES["odrive-leg"])
    assert cfg.bus.channel == "can0" and cfg.bus.bitrate == 1_000_000
    assert [a.node_id for a in cfg.controller.axes] == [0, 1]
    assert cfg.weights_file == "/var/lib/elegant-stepping/weights.npz"
    text = EXAMPLES["odrive-leg"].read_text()
    for key in ("node_id", "gear_ratio", "direction", "zero_offset_rev", "min_rad", "current_limit_a",
                "vel_limit_rev_s", "watchdog_timeout_s"):
        assert key in text
    assert "calibration" in text.lower() and "odrivetool" in text
    # its calibration values are examples: not confirmed, never armable as it is
    assert cfg.calibration == CalibrationSettings() and cfg.controller.auto_arm is False
    assert cfg.armable_reason().startswith("calibration not confirmed")
    assert str(EXAMPLES["odrive-leg"]) in cfg.armable_reason()
    for step in ("bringup --config", "--json report.json", "config confirm", "--bringup report.json"):
        assert step in text, step
    assert cfg.service.control_socket == "/run/elegant-stepping/control.sock"


def test_the_defaults_are_the_simulated_drivers_own():
    """Set_Limits at arming with the defaults changes nothing in the simulated drivers."""
    from firmware_sim.motor import MotorParams
    from firmware_sim.odrive_axis import DriverConfig

    for axis in ControllerConfig().axes:
        assert axis.current_limit_a == MotorParams().current_limit_a
        assert axis.vel_limit_rev_s == DriverConfig(node_id=0).vel_limit_rev_s
    assert DriverSettings().watchdog_timeout_s == DriverConfig(node_id=0).watchdog_timeout_s


# --------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("name", [*sorted(EXAMPLES), None])
def test_config_show_reads_back_to_the_same_config(name, capsys, tmp_path):
    argv = ["config", "show"] + ([] if name is None else [str(EXAMPLES[name])])
    assert main(argv) == 0
    shown = capsys.readouterr().out
    expected = DeployConfig() if name is None else load_config(EXAMPLES[name])
    assert config_from_toml(shown) == expected
    assert load_config(write(tmp_path, shown)) == expected  # a saved `show` is a complete config file
    assert set(tomllib.loads(shown)) == {"bus", "controller", "axes", "drivers", "weights", "service", "calibration",
                                         *MODEL}
    assert config_from_toml(to_toml(expected, comments=False)) == expected


finite = dict(allow_nan=False, allow_infinity=False)


@hypothesis_settings(max_examples=60, deadline=None)
@given(channel=st.text(min_size=1, max_size=15).filter(lambda t: t == t.strip() and "\x00" not in t),
       gear=st.floats(0.1, 1000.0, **finite), offset=st.floats(-1000.0, 1000.0, **finite),
       rate=st.floats(50.0, 1000.0, **finite), noise=st.floats(0.0001, 1.0, **finite),
       beams=st.lists(st.floats(0.001, 0.5, **finite), min_size=1, max_size=8, unique=True),
       learning=st.booleans())
def test_any_valid_config_round_trips_exactly(channel, gear, offset, rate, noise, beams, learning):
    base = ControllerConfig()
    hip = dataclasses.replace(base.axis("hip"), gear_ratio=gear, zero_offset_rev=offset,
                              min_rad=-0.1, max_rad=0.1)
    ctl = dataclasses.replace(
        base, rate_hz=rate, axes=(hip, base.axis("knee")),
        range_filter=dataclasses.replace(base.range_filter, noise_m=noise),
        height=dataclasses.replace(base.height, beam_heights_m=tuple(sorted(beams))),
        learner=dataclasses.replace(base.learner, learning=learning))
    cfg = DeployConfig(bus=BusSettings("virtual", channel), controller=ctl)
    problems = check_config(cfg)
    if problems:  # a float32 joint range too narrow for a large offset: refused, by name
        assert all(p.startswith("[axes.hip]") for p in problems), problems
        return
    assert config_from_toml(to_toml(cfg)) == cfg


@given(st.text())
def test_strings_are_escaped_for_toml(text):
    assert tomllib.loads(f"x = {toml_string(text)}")["x"] == text


def test_write_config_refuses_an_invalid_config_and_writes_a_valid_one(tmp_path):
    ctl = dataclasses.replace(ControllerConfig(), rate_hz=20.0)  # 3 commands take 0.15 s: over the watchdog
    with pytest.raises(ConfigError, match="drivers.watchdog_timeout_s"):
        write_config(tmp_path / "c.toml", DeployConfig(controller=ctl))
    assert not (tmp_path / "c.toml").exists()
    path = write_config(tmp_path / "c.toml", DeployConfig(), header="a test")
    assert load_config(path) == DeployConfig() and path.read_text().startswith("# a test\n")


# --------------------------------------------------------------------------- the schema
def test_the_schema_covers_every_field_of_the_dataclasses():
    keys = {section: {s.key for s in settings} for section, settings in SECTIONS.items()}
    assert keys["bus"] == {f.name for f in dataclasses.fields(BusSettings)}
    assert keys["drivers"] == {f.name for f in dataclasses.fields(DriverSettings)}
    assert keys["weights"] == {f.name for f in dataclasses.fields(WeightsSettings)}
    assert keys["axes.hip"] == keys["axes.knee"] == {f.name for f in dataclasses.fields(AxisConfig)} - {"name"}
    base = ControllerConfig()
    for section in MODEL:
        assert keys[section] == {f.name for f in dataclasses.fields(getattr(base, section))}, section
    assert {f.name for f in dataclasses.fields(ControllerConfig)} == (
        keys["controller"] | set(MODEL) | {"axes", "sensor_node_id"})  # the sensor board's id is the contract's


def _bound_cases():
    for section, settings in SECTIONS.items():
        for s in settings:
            if s.kind in ("float", "int") and s.lo is not None:
                for bound in (s.lo, s.hi):
                    yield section, s.key, (int(bound) if s.kind == "int" else float(bound))


_SIMULATED_LEG = {"bus": {"channel": "vcan0"}}
"""The base document of the bound cases: a simulated leg, where every default holds (a real bus
needs its calibration in the file, test_every_default_is_in_its_range)."""

_PARTNERS = {
    # (setting, bound): the other settings that make a configuration holding that bound, where a
    # cross-field check refuses it with the rest at their defaults.
    ("bus.bitrate", 10000): {"controller.rate_hz": 10.0, "controller.heartbeat_period_s": 0.2,
                             "drivers.watchdog_timeout_s": 0.5},  # the bus load, then what 10 Hz needs
    ("controller.rate_hz", 10.0): {"controller.heartbeat_period_s": 0.2, "drivers.watchdog_timeout_s": 0.5},
    ("controller.heartbeat_period_s", 0.001): {"controller.silence_periods": 10.0},
    ("controller.silence_periods", 100.0): {"controller.stale_heartbeat_periods": 100.0,
                                            "controller.heartbeat_period_s": 0.02},
    ("controller.stale_heartbeat_periods", 1.0): {"controller.silence_periods": 1.0},
    ("axes.knee.node_id", 0): {"axes.hip.node_id": 1},
    ("drivers.watchdog_timeout_s", 0.005): {"controller.rate_hz": 600.0},
    ("cpg.burst_s", 0.05): {"cpg.burst_min_s": 0.05},
    ("cpg.burst_s", 5.0): {"cpg.burst_max_s": 5.0},
    ("cpg.burst_min_s", 5.0): {"cpg.burst_max_s": 5.0, "cpg.burst_s": 5.0},
    ("cpg.burst_max_s", 0.05): {"cpg.burst_min_s": 0.05, "cpg.burst_s": 0.05},
    ("gait.stance_press_m", 0.05): {"geometry.shank_m": 0.26},
    ("geometry.thigh_m", 0.01): {"geometry.shank_m": 0.5},
    ("geometry.shank_m", 0.01): {"geometry.thigh_m": 0.5},
    ("geometry.hip_height_m", 4.0): {"geometry.thigh_m": 2.0, "geometry.shank_m": 2.0},
    ("encoder.max_range_m", 0.01): {"encoder.cell_width_m": 0.01},
    ("encoder.max_range_m", 10.0): {"range_filter.max_range_m": 10.0},
    ("range_filter.max_range_m", 0.01): {"encoder.max_range_m": 0.01, "encoder.cell_width_m": 0.01},
    ("gait.tuck_land_phase", 0.1): {"gait.tuck_forward_phase": 0.0},
}

_UNREACHABLE = {
    # (setting, bound): why no configuration holds it (a cross-field check refuses every one), in
    # words the refusal must hold.
    ("controller.rate_hz", 5000.0): "over 70% of the bus",  # at most about 1300 Hz on a 1 Mbit/s bus
    ("controller.heartbeat_period_s", 10.0): "the node-silence timeout",  # at least 10 s, over the 2 s allowed
    ("axes.hip.min_rad", math.tau): "must be below",  # max_rad cannot exceed 2 pi
    ("axes.hip.max_rad", -math.tau): "must be below",
    ("axes.knee.min_rad", math.tau): "must be below",
    ("axes.knee.max_rad", -math.tau): "must be below",
    # min_bus_voltage_v must be below max_bus_voltage_v (HealthConfig), both in [0, 100] V
    ("health.min_bus_voltage_v", 100.0): "health.max_bus_voltage_v",
    ("health.max_bus_voltage_v", 0.0): "health.min_bus_voltage_v",
    # the tucked swing's full amplitude must be above the one it starts from, both in [1, 5]
    ("gait.tuck_from_amplitude", 5.0): "must be above gait.tuck_from_amplitude",
    ("gait.tuck_full_amplitude", 1.0): "must be above gait.tuck_from_amplitude",
}


def _document(values: dict) -> dict:
    """A parsed TOML document: the simulated leg plus ``values`` (dotted setting -> value)."""
    data = {section: dict(table) for section, table in _SIMULATED_LEG.items()}
    for dotted, value in values.items():
        section, key = dotted.rsplit(".", 1)
        if section.startswith("axes."):
            data.setdefault("axes", {}).setdefault(section[5:], {})[key] = value
        else:
            data.setdefault(section, {})[key] = value
    return data


def _built_value(cfg: DeployConfig, dotted: str):
    """The value of ``dotted`` in a built configuration (its dataclasses, not its tables)."""
    section, key = dotted.rsplit(".", 1)
    if section.startswith("axes."):
        return getattr(cfg.controller.axis(section[5:]), key)
    if section == "controller":
        return getattr(cfg.controller, key)
    if section in MODEL:
        return getattr(getattr(cfg.controller, section), key)
    return getattr(getattr(cfg, section), key)


@pytest.mark.parametrize("section,key,value", list(_bound_cases()))
def test_the_schema_is_never_looser_than_the_dataclasses(section, key, value):
    """Every value the schema's field and cross-field checks accept builds its dataclasses (whose
    own checks would report it less clearly): here each bound of each range, on a simulated leg
    with the rest default, or with the partner settings a cross-field check asks for
    (:data:`_PARTNERS`), is accepted and built, and the built dataclasses hold it. A bound no
    configuration can hold (:data:`_UNREACHABLE`) is refused naming it and why. No case passes
    without building or checking a refusal."""
    dotted = f"{section}.{key}"
    case = (dotted, value)
    if case in _UNREACHABLE:
        _, problems = validate_tables(_document({dotted: value}))
        assert problems and all(dotted in p for p in problems), problems
        assert any(_UNREACHABLE[case] in p for p in problems), problems
        return
    partners = _PARTNERS.get(case, {})
    if partners:  # the partners are needed: without them a cross-field check refuses the bound, by name
        _, problems = validate_tables(_document({dotted: value}))
        assert problems and all(dotted in p for p in problems), problems
    tables, problems = validate_tables(_document({**partners, dotted: value}))
    assert problems == []
    cfg = _build(tables)
    assert _built_value(cfg, dotted) == value and type(_built_value(cfg, dotted)) is type(value)
    for other, v in partners.items():
        assert _built_value(cfg, other) == v


def test_the_bound_cases_cover_every_range_and_their_tables_name_real_cases():
    """Every partner and unreachable entry is one of the bound cases (a renamed or moved setting
    cannot leave a stale entry that silently stops applying)."""
    cases = {(f"{section}.{key}", value) for section, key, value in _bound_cases()}
    assert set(_PARTNERS) <= cases and set(_UNREACHABLE) <= cases
    assert not set(_PARTNERS) & set(_UNREACHABLE)
    assert len(cases) == len(list(_bound_cases()))  # no bound listed twice


def test_every_default_is_in_its_range():
    tables = config_tables(DeployConfig())
    assert validate_tables({"bus": {"channel": "vcan0"}})[1] == []  # on a simulated bus, every default holds
    for section, settings in SECTIONS.items():
        for s in settings:
            value = tables[section][s.key]
            parsed, problem = s.parse(list(value) if isinstance(value, tuple) else value)
            assert problem is None, (section, s.key, problem)


def _dataclass_with(section: str, key: str, value):
    """The dataclass behind ``section`` built with ``key = value``, the rest default."""
    base = ControllerConfig()
    if section.startswith("axes."):
        return dataclasses.replace(base.axis(section.split(".")[1]), **{key: value})
    if section == "controller":
        return dataclasses.replace(base, **{key: value})
    if section in MODEL:
        return dataclasses.replace(getattr(base, section), **{key: value})
    return {"bus": BusSettings, "drivers": DriverSettings, "weights": WeightsSettings, "service": ServiceSettings,
            "calibration": CalibrationSettings}[section](**{key: value})


@pytest.mark.parametrize("section,key", [(section, s.key) for section, settings in SECTIONS.items()
                                         for s in settings if s.lo is not None])
def test_the_dataclasses_refuse_what_the_schema_refuses(section, key):
    """One declaration, two checks: a value just outside a field's range is refused by the TOML
    schema and by the dataclass on creation, both naming the field and the same range."""
    s = {x.key: x for x in SECTIONS[section]}[key]
    bad = s.hi + 1 if s.kind == "int" else s.hi + max(abs(s.hi), 1.0)
    value = (bad,) if s.kind == "floats" else bad
    _, problems = validate_tables({"axes": {section[5:]: {key: value}}} if section.startswith("axes.") else
                                  {section: {key: list(value) if s.kind == "floats" else value}})
    assert any(p.startswith(f"{section}.{key} = ") and s._range() in p for p in problems), problems
    prefix = "" if section == "controller" else f"{section}."
    with pytest.raises(ValueError, match=rf"^{re.escape(prefix + key)} .*\[{re.escape(str(s.lo))}, "
                                         rf"{re.escape(str(s.hi))}\]"):
        _dataclass_with(section, key, value)


# --------------------------------------------------------------------------- bad values
BAD = [
    # (dotted key, TOML value, words the message must hold: the field, its unit, its range)
    ("bus.interface", '"sockecan"', ["socketcan", "virtual"]),
    ("bus.channel", '""', ["channel"]),
    ("bus.bitrate", "300000", ["bit/s", "1000000", "standard"]),
    ("bus.bitrate", "2000000", ["[10000, 1000000] bit/s"]),
    ("controller.rate_hz", "1", ["[10, 5000] Hz"]),
    ("controller.heartbeat_period_s", "0", ["[0.001, 10] s"]),
    ("controller.silence_periods", "0.5", ["[1, 100] heartbeat periods"]),
    ("controller.stale_heartbeat_periods", "2000", ["[1, 1000] heartbeat periods"]),
    ("controller.bringup_timeout_s", "-1", ["[0.01, 600] s"]),
    ("controller.late_factor", "0.5", ["[1, 100] control periods"]),
    ("controller.max_dt_factor", "0", ["[1, 100] control periods"]),
    ("axes.knee.gear_ratio", "-6", ["axes.knee.gear_ratio = -6: must be in [0.1, 1000] rev/rev"]),
    ("axes.hip.node_id", "64", ["[0, 63] (CAN node id)"]),
    ("axes.hip.node_id", "16", ["not 16", "sensor board"]),
    ("axes.knee.direction", "0", ["1 or -1"]),
    ("axes.hip.zero_offset_rev", "1e9", ["[-1000, 1000] rev"]),
    ("axes.hip.min_rad", "-7.0", ["[-6.28319, 6.28319] rad"]),
    ("axes.knee.max_rad", "inf", ["rad"]),
    ("axes.hip.current_limit_a", "0", ["[0.1, 200] A"]),
    ("axes.knee.vel_limit_rev_s", "100", ["[0.1, 80] rev/s"]),
    ("drivers.watchdog_timeout_s", "0", ["[0.005, 1] s"]),
    ("weights.path", '"weights.txt"', [".npz"]),
    ("weights.save_every_s", "0", ["[0.1, 86400] s"]),
    ("weights.generations", "0", ["[1, 100] (files)"]),
    ("service.control_socket", '""', ["control socket"]),
    ("service.control_socket", '"/' + "x" * 120 + '.sock"', ["at most 107 bytes"]),
    ("service.control_group", '"two words"', ["group name"]),
    ("service.records_max_bytes", "10", ["[10000, 1000000000000] bytes"]),
    ("service.records_keep", "-1", ["[0, 1000] (files)"]),
    ("calibration.confirmed", '"yes"', ["must be true or false"]),
    ("calibration.confirmed_at", '"yesterday"', ["ISO 8601"]),
    ("calibration.confirmed_at", '"2025-01-31T12:00:00"', ["UTC"]),
    ("calibration.bringup", '"two\\nlines"', ["one line"]),
    ("cpg.stance_s", "0", ["[0.05, 5] s"]),
    ("cpg.units_per_half", "9", ["[1, 8] units"]),
    ("gait.step_height_m", "0.5", ["[0, 0.3] m"]),
    ("gait.ground_speed_m_s", "-1", ["[0, 3] m/s"]),
    ("geometry.thigh_m", "0", ["[0.01, 2] m"]),
    ("learner.learning_rate_s", "2", ["[0, 1] s"]),
    ("encoder.cell_width_m", "0", ["[0.001, 1] m"]),
    ("range_filter.noise_m", "0", ["[0.0001, 1] m"]),
    ("range_filter.accel_noise_m_s2", "-0.1", ["[0, 100] m/s^2"]),
    ("range_filter.reacquire_after", "0", ["[1, 1000] readings"]),
    ("reflexes.touchdown_phase", "1.5", ["[0, 1] (fraction of the swing)"]),
    ("reflexes.lift_amplitude", "10", ["[0.1, 5] x step height"]),
    ("height.window", "0", ["[1, 1000] samples"]),
    ("height.beam_heights_m", "[0.6]", ["[0.001, 0.5] m"]),
    ("height.beam_heights_m", "[0.09, 0.05]", ["strictly increasing"]),
    ("height.seen_fraction", "0", ["[0.01, 1] (fraction of samples)"]),
    ("health.max_motor_temp_c", "500", ["[0, 200] C"]),
    ("health.read_period_s", "0", ["[0.001, 10] s"]),
]


def _file(dotted: str, literal: str) -> str:
    section, key = dotted.rsplit(".", 1)
    return f"[{section}]\n{key} = {literal}\n"


def test_every_section_has_a_bad_value_case():
    assert {dotted.rsplit(".", 1)[0] for dotted, _, _ in BAD} == set(SECTIONS)


@pytest.mark.parametrize("dotted,literal,words", BAD, ids=[f"{d}={v}" for d, v, _ in BAD])
def test_a_bad_value_exits_3_naming_the_field_its_unit_and_range(dotted, literal, words, tmp_path, capsys):
    path = write(tmp_path, _file(dotted, literal))
    rc, out, err = check(capsys, path)
    assert rc == 3 and not out
    line = next(x for x in err.splitlines() if dotted in x)
    assert line.startswith(f"{path}: {dotted} = ")
    for word in words:
        assert word in line, line


TYPES = [
    ("controller.rate_hz", '"fast"', ["must be a number in [10, 5000] Hz", "not a string"]),
    ("axes.hip.node_id", "1.0", ["must be an integer in [0, 63] (CAN node id)", "not a float"]),
    ("axes.knee.direction", "-1.0", ["must be an integer", "1 or -1", "not a float"]),
    ("bus.bitrate", "1e6", ["must be an integer", "bit/s", "not a float"]),
    ("bus.interface", "3", ["must be a string", "not an integer"]),
    ("learner.learning", "1", ["must be true or false", "not an integer"]),
    ("gait.ramp_s", "true", ["must be a number in [0, 10] s", "not true/false"]),
    ("height.beam_heights_m", "0.05", ["must be an array", "[0.001, 0.5] m"]),
    ("height.beam_heights_m", '[0.05, "x"]', ["item 1", "must be a number in [0.001, 0.5] m"]),
    ("weights.path", "0", ["must be a string"]),
]


@pytest.mark.parametrize("dotted,literal,words", TYPES, ids=[f"{d}={v}" for d, v, _ in TYPES])
def test_a_wrong_type_is_an_error_naming_the_field(dotted, literal, words, tmp_path, capsys):
    rc, _, err = check(capsys, write(tmp_path, _file(dotted, literal)))
    assert rc == 3
    line = next(x for x in err.splitlines() if dotted in x)
    for word in words:
        assert word in line, line


@pytest.mark.parametrize("text,words", [
    ("[bus]\nchanel = \"can0\"\n", ["bus.chanel: unknown setting", "interface, channel, bitrate"]),
    ("[controller]\nsensor_node_id = 16\n", ["controller.sensor_node_id: unknown setting", "rate_hz"]),
    ("[buss]\nchannel = \"can0\"\n", ["[buss]: unknown section", "[bus]", "[axes.hip]", "[height]"]),
    ("[axes.elbow]\nnode_id = 2\n", ["[axes.elbow]: unknown axis", "[axes.hip], [axes.knee]"]),
    ("[axes]\nnode_id = 2\n", ["axes.node_id = 2", "[axes.hip] or [axes.knee]", "gear_ratio"]),
    ("rate_hz = 500\n", ["rate_hz = 500: unknown top-level setting", "[controller]"]),
    ("bus = \"can0\"\n", ["bus = \"can0\": must be a table [bus]"]),
])
def test_unknown_keys_and_sections_are_errors_listing_the_known_ones(text, words, tmp_path, capsys):
    rc, _, err = check(capsys, write(tmp_path, text))
    assert rc == 3
    for word in words:
        assert word in err, err


def test_a_missing_file_or_a_folder_is_a_clear_error(tmp_path, capsys):
    rc, _, err = check(capsys, tmp_path / "nope.toml")
    assert rc == 3 and f"{tmp_path / 'nope.toml'}: cannot read the configuration: No such file" in err
    rc, _, err = check(capsys, tmp_path)
    assert rc == 3 and "cannot read the configuration" in err
    (tmp_path / "bin.toml").write_bytes(b"[bus]\nchannel = \"\xff\"\n")
    rc, _, err = check(capsys, tmp_path / "bin.toml")
    assert rc == 3 and "not UTF-8" in err


def test_malformed_toml_names_the_line(tmp_path, capsys):
    path = write(tmp_path, "[bus]\nchannel = \"can0\"\nbitrate = 1000000 bit/s\n")
    rc, _, err = check(capsys, path)
    assert rc == 3 and f"{path}: not valid TOML" in err and "line 3" in err and "'bitrate = 1000000 bit/s'" in err
    rc, _, err = check(capsys, write(tmp_path, "[bus]\nbitrate = 1000000\nbitrate = 500000\n"))
    assert rc == 3 and "line 3" in err
    rc, _, err = check(capsys, write(tmp_path, '{"rate_hz": 500}', "old.json"))
    assert rc == 3 and "looks like JSON" in err


@pytest.mark.parametrize("depth", [20, 400, 500, 5000])
@pytest.mark.parametrize("shape", ["array", "table"])
def test_a_document_nested_hundreds_deep_is_one_line_naming_the_file_exit_3(depth, shape, tmp_path, capsys):
    """tomllib raises RecursionError near 500 levels, and validation recursed on what it could parse
    (a RecursionError between 350 and 475): both are now one problem naming the file."""
    value = "[" * depth + "]" * depth if shape == "array" else "{a=" * depth + "1" + "}" * depth
    path = write(tmp_path, f"[controller]\nrate_hz = {value}\n")
    rc, out, err = check(capsys, path)
    lines = err.strip().splitlines()
    assert rc == 3 and not out and "Traceback" not in err and "RecursionError" not in err
    assert len(lines) == 2 and lines[0].startswith(f"{path}: ") and "nested" in lines[0], err
    assert len(lines[0]) < 400  # the value is not quoted whole
    assert lines[1] == f"config check: {path}: 1 problem"
    with pytest.raises(ConfigError, match="nested"):
        load_config(path)


def test_the_daemon_refuses_a_deeply_nested_file_in_one_line_exit_3(tmp_path, capsys):
    path = write(tmp_path, "x = " + "[" * 500 + "]" * 500 + "\n")
    assert main(["controller", "--interface", "virtual", "--channel", "x", "--config", str(path)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"elegant-stepping controller: error: {path}: ") and "nested" in err[0]


def test_an_integer_python_will_not_convert_is_a_toml_problem(tmp_path, capsys):
    path = write(tmp_path, "[controller]\nrate_hz = " + "9" * 5000 + "\n")
    rc, _, err = check(capsys, path)
    assert rc == 3 and f"{path}: not valid TOML" in err and "4300" in err and "Traceback" not in err


def test_config_errors_are_input_errors_exit_3():
    from controller.errors import EXIT_INPUT, InputError
    from controller.settings.file import ConfirmRefused

    assert issubclass(ConfigError, InputError) and issubclass(ConfigError, ValueError)
    assert ConfigError(["x"]).exit_code == EXIT_INPUT and ConfirmRefused("no").exit_code == EXIT_INPUT
    two = ConfigError(["a = 1: bad", "b = 2: bad"], "leg.toml")
    import io

    stream = io.StringIO()
    one = two.reported(stream)
    assert stream.getvalue().splitlines() == ["leg.toml: a = 1: bad", "leg.toml: b = 2: bad"]
    assert isinstance(one, InputError)
    assert str(one) == "leg.toml: 2 problems in the configuration (each on its own line above)"
    single = ConfigError(["a = 1: bad"], "leg.toml")
    stream = io.StringIO()
    assert single.reported(stream) is single and stream.getvalue() == ""


CROSS = [
    ("[axes.hip]\nnode_id = 1\n", ["axes.hip.node_id = 1 and axes.knee.node_id = 1", "different CAN node ids"]),
    ("[axes.knee]\nmin_rad = 0.5\n", ["axes.knee.min_rad = 0.5 rad must be below axes.knee.max_rad = 0.0 rad"]),
    ("[drivers]\nwatchdog_timeout_s = 0.005\n",
     ["drivers.watchdog_timeout_s = 0.005 s", "at least 3 commands", "at least 0.006 s"]),
    ("[controller]\nsilence_periods = 3.5\nstale_heartbeat_periods = 2\n",
     ["controller.stale_heartbeat_periods = 2.0 must be at least controller.silence_periods = 3.5"]),
    ("[controller]\nsilence_periods = 30\nstale_heartbeat_periods = 40\n",
     ["controller.heartbeat_period_s x controller.silence_periods", "= 3 s", "must be in [0.01, 2] s"]),
    ("[controller]\nrate_hz = 2000\n[bus]\nbitrate = 500000\n",
     ["controller.rate_hz = 2000.0 Hz on bus.bitrate = 500000 bit/s", "over 70% of the bus", "at most 648.148 Hz"]),
    ("[cpg]\nburst_s = 0.7\n", ["cpg.burst_s = 0.7: must be in [cpg.burst_min_s, cpg.burst_max_s] = [0.15, 0.6] s"]),
    ("[cpg]\nburst_min_s = 0.5\nburst_max_s = 0.4\n", ["cpg.burst_max_s = 0.4 s must be at least cpg.burst_min_s"]),
    ("[encoder]\nmax_range_m = 4.0\n",
     ["encoder.max_range_m = 4.0 m must be at most range_filter.max_range_m = 3.0 m"]),
    ("[encoder]\ncell_width_m = 0.5\nmax_range_m = 0.2\n", ["encoder.cell_width_m = 0.5 m must be at most"]),
    ("[geometry]\nhip_height_m = 0.8\n", ["geometry.hip_height_m", "cannot reach the ground", "0.5 m"]),
    ("[bus]\ninterface = \"socketcan\"\nchannel = \"a-very-long-can-name\"\n", ["at most 15 characters"]),
    ("[axes.hip]\nzero_offset_rev = 999.3\nmin_rad = 0.0\nmax_rad = 0.000001\n", ["[axes.hip]", "float32"]),
]


@pytest.mark.parametrize("text,words", CROSS, ids=[c[1][0][:40] for c in CROSS])
def test_cross_field_errors(text, words, tmp_path, capsys):
    rc, _, err = check(capsys, write(tmp_path, text))
    assert rc == 3
    for word in words:
        assert word in err, err


def test_every_problem_in_a_file_is_reported_at_once(tmp_path, capsys):
    text = ("[bus]\nbitrate = 300000\n[axes.knee]\ngear_ratio = -6\nnode_id = 0\n"
            "[learner]\nlearning = \"yes\"\nfoo = 1\n")
    rc, _, err = check(capsys, write(tmp_path, text))
    lines = err.strip().splitlines()
    assert rc == 3 and len(lines) == 9, err  # eight problems, one per line, and the count
    assert lines[-1].endswith("8 problems")
    # on can0 (the default channel) the file must also give [bus] interface, channel and every calibration key
    assert sum("not given; on a real CAN bus" in x for x in lines) == 3
    for dotted in ("bus.bitrate", "axes.knee.gear_ratio", "learner.learning", "learner.foo", "axes.knee.node_id = 0"):
        assert any(dotted in x for x in lines), dotted


def test_config_show_of_a_bad_file_exits_3(tmp_path, capsys):
    assert main(["config", "show", str(write(tmp_path, "[cpg]\nstance_s = 0\n"))]) == 3
    out = capsys.readouterr()
    assert not out.out and "cpg.stance_s = 0: must be in [0.05, 5] s" in out.err


def test_a_partial_file_keeps_the_defaults_and_relative_weights_are_beside_it(tmp_path):
    cfg = load_config(write(tmp_path, "[bus]\nchannel = \"vcan0\"\n[weights]\npath = \"state/w.npz\"\n"
                                      "[learner]\nlearning = false\n[service]\ncontrol_socket = \"run/c.sock\"\n"))
    assert cfg.weights_file == str(tmp_path / "state" / "w.npz")
    assert cfg.service.control_socket == str(tmp_path / "run" / "c.sock")  # the same rule as the weights'
    assert cfg.controller.learner.learning is False
    assert dataclasses.replace(cfg.controller, learner=ControllerConfig().learner) == ControllerConfig()
    assert config_from_dict({"bus": {"interface": "virtual"}}) == DeployConfig(bus=BusSettings(interface="virtual"))
    assert config_from_dict({"bus": {"channel": "vcan3"}}).source == ""


# --------------------------------------------------------------------------- the daemon
def test_the_daemon_settings_take_the_file_then_the_command_line(tmp_path):
    path = write(tmp_path, "[bus]\ninterface = \"virtual\"\nchannel = \"bus-a\"\nbitrate = 500000\n"
                           "[weights]\npath = \"w.npz\"\nsave_every_s = 3.0\n[controller]\nrate_hz = 250\n")
    d = daemon_settings(path)
    assert d.bus_kw == {"interface": "virtual", "channel": "bus-a", "bitrate": 500000}
    assert d.weights == str(tmp_path / "w.npz") and d.save_every_s == 3.0 and d.controller.rate_hz == 250.0
    d = daemon_settings(path, channel="bus-b", weights=str(tmp_path / "x.npz"), save_every_s=9.0)
    assert d.bus_kw == {"interface": "virtual", "channel": "bus-b", "bitrate": 500000}
    assert d.weights == str(tmp_path / "x.npz") and d.save_every_s == 9.0
    d = daemon_settings(None, channel="vcan0")  # no file: python-can's own configuration fills in the rest
    assert d.controller == ControllerConfig() and d.weights is None and d.save_every_s == 10.0
    assert d.bus_kw["channel"] == "vcan0"


def test_the_daemon_reads_its_bus_weights_and_controller_from_the_toml_file(tmp_path, capsys):
    channel = f"settings-{uuid.uuid4().hex[:8]}"
    path = write(tmp_path, f"[bus]\ninterface = \"virtual\"\nchannel = \"{channel}\"\n"
                           "[controller]\nbringup_timeout_s = 0.1\n[weights]\npath = \"w.npz\"\n"
                           "[service]\ncontrol_socket = \"c.sock\"\n")
    # no leg: bring-up times out; a FAULT at the end of --seconds is a safety stop
    assert main(["controller", "--config", str(path), "--seconds", "0.4"]) == 5
    final = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert final["phase"] == "fault"  # [controller] bringup_timeout_s, on the [bus] given (no bus arguments)
    assert final["control"]["socket"] == str(tmp_path / "c.sock")  # [service] control_socket, beside the file
    # [weights] path, beside the file: saved at exit unless they did not change (then nothing is written)
    assert final["weights_saved"] is (None if final.get("weights_unchanged") else True)
    assert (tmp_path / "w.npz").exists() is bool(final["weights_saved"])


def test_the_daemon_refuses_a_bad_file_naming_the_field(tmp_path, capsys):
    path = write(tmp_path, "[axes.knee]\ngear_ratio = -6\n")
    assert main(["controller", "--interface", "virtual", "--channel", "x", "--config", str(path)]) == 3
    assert "axes.knee.gear_ratio = -6: must be in [0.1, 1000] rev/rev" in capsys.readouterr().err


def test_replay_reads_the_toml_and_an_old_json_with_a_warning(tmp_path, caplog):
    path = write_config(tmp_path / "controller.toml",
                        DeployConfig(controller=dataclasses.replace(ControllerConfig(), rate_hz=250.0)))
    assert load_controller_config(path).rate_hz == 250.0
    old = write(tmp_path, '{"rate_hz": 125}', "controller.json")
    with caplog.at_level("WARNING"):
        assert load_controller_config(old).rate_hz == 125
    assert "before the switch to TOML" in caplog.text
    assert load_controller_config(None) == ControllerConfig()


# --------------------------------------------------------------------------- Set_Limits at arming
def test_set_limits_carries_the_axis_limits():
    from controller.io.axis import AxisLink
    from protocol import BusContract

    contract = BusContract.load()
    link = AxisLink(AxisConfig("knee", 5, -1.0, 0.0, current_limit_a=12.5, vel_limit_rev_s=7.25), contract)
    msg = link.limits_frame()
    assert msg.arbitration_id == (5 << 5) | 0x0F and not msg.is_extended_id
    assert contract.codec("Set_Limits").unpack(msg.data) == pytest.approx((7.25, 12.5))


def test_the_controller_sends_set_limits_at_arming_and_the_drivers_take_them():
    from hil.lockstep.harness import Lockstep, LockstepConfig
    from protocol import AxisState

    base = ControllerConfig()
    axes = tuple(dataclasses.replace(a, current_limit_a=12.0 if a.name == "hip" else 9.0, vel_limit_rev_s=15.0)
                 for a in base.axes)
    with Lockstep(LockstepConfig(seed=0, controller=dataclasses.replace(base, axes=axes))) as ls:
        for _ in range(1500):
            ls.step()
        drivers = ls.leg.axes
        assert all(a.state == AxisState.CLOSED_LOOP_CONTROL for a in drivers.values())
        assert ls.loop.io.tx["Set_Limits"] >= 2 and all(a.stats["rx"]["Set_Limits"] >= 1 for a in drivers.values())
        assert (drivers["hip"].current_limit_a, drivers["knee"].current_limit_a) == (12.0, 9.0)
        assert drivers["hip"].vel_limit_rev_s == drivers["knee"].vel_limit_rev_s == 15.0
        assert drivers["hip"].torque_limit_nm == pytest.approx(0.083 * 12.0)


def test_vel_and_current_limits_are_validated_on_the_axis_config():
    with pytest.raises(ValueError, match=r"axes.hip.current_limit_a must be in \[0.1, 200.0\] A"):
        AxisConfig("hip", 0, -1.0, 1.0, current_limit_a=0.0)
    with pytest.raises(ValueError, match="vel_limit_rev_s"):
        AxisConfig("hip", 0, -1.0, 1.0, vel_limit_rev_s=math.inf)


@pytest.mark.parametrize("in_uml", [False, True])
def test_a_hil_session_writes_a_controller_toml_the_daemon_reads(in_uml, tmp_path, capsys, monkeypatch):
    """What hil.session.run and hil.bench.socketcan write (natively and inside User-Mode Linux, where the
    node-silence timeout is longer), read back by the daemon as it starts it (bus on the command line)."""
    import hil.session.run as hilrun
    from controller.settings.daemon import session_config
    from hil import profile
    from hil.experiments.learn import LearnConfig

    ctl = hilrun.session_controller_config(LearnConfig(trials=1, seed=0, range_noise_m=0.0, learning=False),
                                           profile.UML if in_uml else profile.NATIVE)
    path = write_config(tmp_path / "controller.toml", session_config(ctl, "vcan0", tmp_path / "control.sock"),
                        header="a session")
    assert load_config(path).controller == ctl and load_config(path).bus.channel == "vcan0"
    assert load_controller_config(path) == ctl  # what replay reads beside the log
    channel = f"session-{uuid.uuid4().hex[:8]}"
    assert main(["controller", "--interface", "virtual", "--channel", channel, "--config", str(path),
                 "--seconds", "0.1"]) == 0  # no leg: still waiting for its nodes when the time is up
    final = json.loads(capsys.readouterr().err.strip().splitlines()[-1])
    assert final["phase"] == "wait_nodes" and final["weights_source"] is None
