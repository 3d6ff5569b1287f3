"""Configuration (hdrd/config.py) and the shipped config/hdrd.yaml.

Every key is validated (type, range, finite, known key); a bad file fails with one line that
names the key, the value and what is allowed.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd import configload
from hdrd.config import Config, ConfigError
from hdrd.configload import apply_overrides, load_config, parse_config
from hdrd.core.hdr import HdrParams
from hdrd.errors import EX_CONFIG, HdrdError
from hdrd.io.net.publish import parse_hostport

SHIPPED = Path(__file__).resolve().parent.parent / "config" / "hdrd.yaml"


def config_field_keys() -> list[str]:
    """Every 'section.key' a configuration may set: each section's fields, hdr's parameters
    flat beside its ``method`` (not ``params``), less ``i_c_auto`` (``hdr.i_c: auto`` sets it)."""
    keys: list[str] = []
    for sec in fields(Config):
        for f in fields(getattr(Config(), sec.name)):
            if f.name == "params":
                keys.extend(f"{sec.name}.{p.name}" for p in fields(HdrParams))
            elif f.name != "i_c_auto":
                keys.append(f"{sec.name}.{f.name}")
    return keys


NAN, INF = math.nan, math.inf


def get(cfg: Config, key: str) -> Any:
    section, name = key.split(".")
    sec = getattr(cfg, section)
    if key == "hdr.i_c" and sec.i_c_auto:
        return "auto"
    if section == "hdr" and name != "method":
        return getattr(sec.params, name)
    return getattr(sec, name)


def nested(key: str, value: Any) -> dict[str, Any]:
    section, name = key.split(".")
    return {section: {name: value}}


# One row per key: a valid non-default value (to show it lands in the right place) and bad
# values of each kind that applies: wrong type, out of range, NaN/inf.
TABLE: dict[str, tuple[Any, list[Any]]] = {
    "device.port": ("/dev/ttyUSB0", [123, "", "   ", None, ["/dev/ttyUSB0"], True]),
    "device.protocol": ("hdr-text", ["hdr-xml", "", 1, None]),
    "device.baud": (9600, [49, 20_000_001, 0, -9600, 9600.5, 9600.0, "9600", True, NAN]),
    "device.reconnect_min_s": (1, [0, -1.0, NAN, INF, "1", True, None, 3601]),
    "device.reconnect_max_s": (30.0, [0, -1, NAN, INF, "30", [30], 1e308]),
    "device.stale_after_s": (5.0, [0.0, -0.1, NAN, -INF, "5s", 1e308]),
    "device.clock_rate": (4.0, [-1.0, NAN, INF, "4x", 1e7, True]),
    "sensor.adc_bits": (12, [7, 33, 0, 16.0, "16", True, NAN]),
    "sensor.vref_v": (3.3, [0, -5.0, NAN, INF, 10**400, "5V", 1e308, 1e-320]),
    "sensor.null_v": (1.65, [-0.1, NAN, INF, "2.5", 1e308]),
    "sensor.scale_v_per_dps": (0.0066, [0, -0.01, NAN, INF, None, 1e-300, 1e308]),
    "sensor.polarity": (-1, [0, 2, -2, 1.0, "up", True, NAN]),
    "sensor.range_dps": (100.0, [0, -200.0, INF, NAN, "200", 1e308]),
    "sensor.ref_divider": (3.0, [0.0, -2.0, NAN, INF, 1e-300, 1e308]),
    "sensor.supply_nominal_v": (3.3, [0.0, -5.0, NAN, INF, 1e-320, 1e308]),
    "sensor.supply_tolerance": (0.1, [0.0, -0.05, 1.5, NAN, INF, "5 %"]),
    "sensor.supply_max_step_v": (0.25, [0.0, -0.1, NAN, INF, 1e308]),
    "hdr.method": ("none", ["kalman", "HDR", 1, None]),
    "hdr.i_c": (0.05, [-0.01, NAN, INF, "0.0422", "Auto", True, 1e308]),
    "hdr.tau": (0.0, [-0.75, NAN, INF, [0.75], 1e308]),
    "hdr.theta_w": (1.0, [0.0, -0.564, NAN, INF, "0.564", 1e308]),
    "hdr.c1": (0.2, [-0.16, NAN, INF, 1e308]),
    "hdr.c2": (2.0, [-1.8, NAN, -INF, 1000, 10.5]),
    "hdr.T": (0.5, [0.0, 0.005, 61.0, -1.0, NAN, INF, "1s"]),
    "hdr.lowpass": (False, ["yes", 1, 0.0, None]),
    "hdr.turn_switch": (False, ["true", 0]),
    "hdr.attenuator": (False, ["false", 1.0]),
    "hdr.enabled": (False, ["off", 0]),
    "calibration.bias_file": ("/var/lib/hdrd/bias.yaml", [5, ["bias.yaml"], True, {"a": 1}]),
    "calibration.t_bias_s": (20, [0, -30.0, NAN, INF, "30", 1e308]),
    "calibration.startup_s": (2.0, [0.0, -1.0, INF, NAN, 1e308, 601]),
    "calibration.on_bad_bias_file": ("calibrate", ["ignore", "", 1, True]),
    "calibration.max_std_dps": (1.0, [0.0, -0.5, NAN, INF]),
    "calibration.max_trend_dps": (0.5, [0.0, -1.0, NAN, INF]),
    "calibration.max_excursion_dps": (5.0, [0.0, -3.0, NAN, INF]),
    "calibration.max_bias_dps": (5.0, [0, -1.0, NAN, INF, 1001, "3"]),
    "calibration.no_data_timeout_s": (30.0, [0, -1.0, NAN, INF, 3601, "10"]),
    "output.heading0_deg": (359.5, [-1.0, -0.001, 360, 360.0, 720.0, NAN, INF, "90"]),
    "output.stdout": (True, ["no", 1, None]),
    "output.udp": (
        ["127.0.0.1:10110", "[::1]:10111"],
        [
            "localhost",
            ["host:0"],
            ["host:65536"],
            [":abc"],
            [1],
            {"a": 1},
            ["a b:10"],
            5,
            [f"h:{p}" for p in range(1000, 1017)],
        ],
    ),
    "output.nmea_udp": (
        ["192.168.1.5:10110"] * 16,
        ["x", ["h:0"], [None], ["h:"], ["192.168.1.5:10110"] * 17],
    ),
    "output.nmea_ths": (True, [1, "true"]),
    "output.nmea_talker": ("HC", ["hc", "H", "HCX", "H1", "ÄB", "", 5, None]),
    "log.level": ("debug", ["verbose", "INFO", 3, None]),
    "log.format": ("json", ["xml", True]),
    "log.bad_frame_interval_s": (60.0, [0.0, -10.0, NAN, INF, 1e308]),
    "simulate.drive": ("highway", ["moon", "", 1]),
    "simulate.seed": (42, [-1, 1.5, "1", True, NAN, 2**32]),
    "simulate.rate_hz": (100.0, [0.5, 10_001.0, 0, NAN, INF]),
    "simulate.speedup": (60.0, [0.0, -1.0, INF, NAN, 1e-300, 1e308]),
    "gpsd.enabled": (True, ["true", 1]),
    "gpsd.host": ("gps.local", ["", " ", 127, None]),
    "gpsd.port": (2948, [0, 65536, -1, 2947.0, "2947", NAN]),
    "gpsd.min_speed_mps": (0.0, [-1.0, NAN, INF]),
    "gpsd.max_fix_age_s": (1.0, [1e308, 10.01, 0.0, -1.0, NAN, "2"]),
    "gpsd.max_epd_deg": (30.0, [0.0, 181.0, INF]),
    "gpsd.align_gain": (0.5, [-0.1, 1.5, NAN]),
    "gpsd.bias_window_s": (60.0, [0.0, -5.0, INF]),
    "gpsd.bias_gain": (1.0, [1.01, -0.3, True]),
    "gpsd.device": ("/dev/ttyUSB1", [" /dev/ttyUSB1", "a\0b", 1, None, ["/dev/ttyUSB1"]]),
    "standstill.enabled": (False, ["no", 0, None]),
    "standstill.from_gyro": (True, ["yes", 1, 1.0]),
    "simulate.grade": ("tactical", ["nav", "", 1]),
    "gyro.grade": ("phone", ["nav", None, 2]),
    "gyro.white_dps_per_rthz": (0.01, [-0.01, 101.0, NAN]),
    "gyro.bias_instability_dps": (0.001, [-1.0, INF, "small"]),
    "gyro.bias_tau_s": (300.0, [0.5, 2e6, NAN]),
    "gyro.rrw_dps_per_sqrt_s": (1e-5, [-1e-5, 1e3, True]),
    "gyro.temp_coeff_dps_per_c": (0.005, [-0.005, 200.0, NAN]),
    "gyro.quant_step_dps": (0.244, [-0.1, 1e9, INF]),
    "gyro.motion_offset_dps": (-0.09, [-5.1, 5.1, INF, NAN]),
    "gyro.motion_offset_sd_dps": (0.004, [-0.1, 5.1, INF]),
    "gyro.stop_scatter_dps": (0.02, [-0.1, 5.1, INF]),
}

BAD_CASES = [(k, v) for k, (_, bad) in TABLE.items() for v in bad]


def test_table_covers_every_key() -> None:
    assert sorted(TABLE) == sorted(config_field_keys())
    assert len(config_field_keys()) == len(set(config_field_keys()))


def check_error(e: ConfigError, key: str, source: str | None = None) -> str:
    msg = str(e)
    assert "\n" not in msg and "\r" not in msg, msg
    assert e.key == key
    where = f" in {source}" if source else ""
    if key == "(file)":  # the file as a whole: said in words, no "key = value"
        assert msg.startswith(f"config error{where}: ") and "(file)" not in msg, msg
        return msg
    if key == "(yaml)":  # its YAML: where in it, then what is wrong
        assert re.match(rf"config error{re.escape(where)}(, line \d+, column \d+)?: .+", msg), msg
        return msg
    shown_key = key if key.isprintable() else repr(key)
    assert msg.startswith(f"config error{where}: {shown_key} = "), msg
    assert re.search(r" = .+: .+", msg), msg
    return msg


@pytest.mark.parametrize("key, value", BAD_CASES, ids=[f"{k}={v!r}" for k, v in BAD_CASES])
def test_bad_value_in_a_file(tmp_path: Path, key: str, value: Any) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(yaml.safe_dump(nested(key, value)))
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = check_error(ei.value, key, str(p))
    assert re.search(r": must (be|not) ", msg), msg  # says what is allowed


@pytest.mark.parametrize("key, value", BAD_CASES, ids=[f"{k}={v!r}" for k, v in BAD_CASES])
def test_bad_value_as_an_override(key: str, value: Any) -> None:
    if value is None:
        # None means "flag not given" to apply_overrides: skipped, the config unchanged.
        assert apply_overrides(Config(), {key: None}) == Config()
        return
    with pytest.raises(ConfigError) as ei:
        apply_overrides(Config(), {key: value})
    check_error(ei.value, key)


@pytest.mark.parametrize("key", sorted(TABLE))
def test_good_value_lands_on_its_key(key: str) -> None:
    good = TABLE[key][0]
    cfg = parse_config(nested(key, good))
    want = tuple(good) if isinstance(good, list) else good
    default = get(Config(), key)
    assert get(cfg, key) == want
    assert type(get(cfg, key)) is (float if key == "hdr.i_c" else type(default))  # auto: text
    # ... and nothing else changed.
    for other in config_field_keys():
        if other != key:
            assert get(cfg, other) == get(Config(), other), other
    over = apply_overrides(Config(), {key: tuple(good) if isinstance(good, list) else good})
    assert over == cfg


@pytest.mark.parametrize("key", sorted(TABLE))
def test_default_value_written_out_is_accepted(key: str) -> None:
    default = get(Config(), key)
    value = list(default) if isinstance(default, tuple) else default
    assert parse_config(nested(key, value)) == Config()


def test_float_keys_take_integers_as_floats() -> None:
    cfg = parse_config({"calibration": {"t_bias_s": 20}, "hdr": {"T": 2}})
    assert cfg.calibration.t_bias_s == 20.0 and isinstance(cfg.calibration.t_bias_s, float)
    assert cfg.hdr.params == HdrParams(T=2.0)


def test_a_single_destination_may_be_a_string() -> None:
    cfg = parse_config({"output": {"udp": "127.0.0.1:10110"}})
    assert cfg.output.udp == ("127.0.0.1:10110",)


# -- unknown keys, sections and file-level errors ----------------------------------------------


@pytest.mark.parametrize("section", [f.name for f in fields(Config)])
def test_unknown_key_in_each_section(tmp_path: Path, section: str) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(f"{section}:\n  bogus_key: 1\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = check_error(ei.value, f"{section}.bogus_key", str(p))
    assert "unknown key (allowed: " in msg
    # The allowed list names the section's real keys.
    real = [k.split(".")[1] for k in config_field_keys() if k.startswith(section + ".")]
    assert all(k in msg for k in real)


def test_hdr_params_is_not_a_key() -> None:
    with pytest.raises(ConfigError, match=r"hdr\.params = .*unknown key"):
        parse_config({"hdr": {"params": {"i_c": 0.05}}})


def test_the_increment_is_auto_or_a_number() -> None:
    assert Config().hdr.i_c_auto and parse_config({"hdr": {"i_c": "auto"}}) == Config()
    given = parse_config({"hdr": {"i_c": 0.0422}})
    assert not given.hdr.i_c_auto and given.hdr.params == Config().hdr.params
    # an override of another hdr key keeps auto; one of i_c sets the number
    assert apply_overrides(Config(), {"hdr.tau": 1.0}).hdr.i_c_auto
    assert not apply_overrides(Config(), {"hdr.i_c": 0.01}).hdr.i_c_auto
    with pytest.raises(ConfigError, match="must be auto or a finite number"):
        parse_config({"hdr": {"i_c": "gyro"}})


@pytest.mark.parametrize(
    ("data", "key", "hint"),
    [
        ({"plus": {"grade": "tactical"}}, "plus", "is now the `gyro:` section"),
        ({"hdr": {"i_c_from": "config"}}, "hdr.i_c_from", "write hdr.i_c: auto"),
    ],
)
def test_old_keys_are_refused_with_what_to_write(data: dict[str, Any], key: str, hint: str) -> None:
    with pytest.raises(ConfigError) as ei:
        parse_config(data)
    assert ei.value.key == key and hint in str(ei.value) and "\n" not in str(ei.value)


def test_unknown_section(tmp_path: Path) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text("devices:\n  port: /dev/ttyUSB0\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = check_error(ei.value, "devices", str(p))
    assert (
        "unknown section (allowed: device, sensor, hdr, calibration, output, log, simulate, gpsd, "
        "standstill, gyro)" in msg
    )


@pytest.mark.parametrize("value", [5, "x", [1, 2], True])
def test_section_must_be_a_mapping(value: Any) -> None:
    with pytest.raises(ConfigError) as ei:
        parse_config({"sensor": value})
    assert "must be a mapping of keys" in check_error(ei.value, "sensor")


def test_empty_section_keeps_defaults() -> None:
    assert parse_config({"device": None, "hdr": {}}) == Config()


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "---\n", "null\n"])
def test_empty_file(tmp_path: Path, text: str) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert "is empty" in check_error(ei.value, "(file)", str(p))


@pytest.mark.parametrize("text", ["- device\n- sensor\n", "just a string\n", "42\n"])
def test_file_that_is_not_a_mapping(tmp_path: Path, text: str) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert "not a mapping of sections" in check_error(ei.value, "(file)", str(p))


@pytest.mark.parametrize(
    "text, line",
    [
        ("device:\n  port: [/dev/ttyUSB0\n", 3),
        ("device:\n  port: a\n   baud: 9600\n", 3),
        ("hdr:\n\ti_c: 0.05\n", 2),
        ("device: {port: x\n", 2),
        ("---\na: 1\n---\nb: 2\n", 3),
    ],
)
def test_yaml_syntax_error(tmp_path: Path, text: str, line: int) -> None:
    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = check_error(ei.value, "(yaml)", str(p))
    assert "YAML syntax error" in msg and f"line {line}," in msg


def test_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert msg_ends(check_error(ei.value, "(file)", str(p)), "no such file")


def msg_ends(msg: str, tail: str) -> bool:
    return msg.endswith(tail)


def test_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as ei:
        load_config(tmp_path)  # a directory
    assert "cannot be read" in check_error(ei.value, "(file)", str(tmp_path))
    p = tmp_path / "latin1.yaml"
    p.write_bytes(b"device:\n  port: /dev/tty\xe9\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert "cannot be read (UnicodeDecodeError)" in check_error(ei.value, "(file)", str(p))


def test_no_path_uses_etc_or_builtin_defaults(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(configload, "DEFAULT_CONFIG_PATH", tmp_path / "absent.yaml")
    assert load_config() == (Config(), "built-in defaults")
    etc = tmp_path / "hdrd.yaml"
    etc.write_text("hdr:\n  method: none\n")
    monkeypatch.setattr(configload, "DEFAULT_CONFIG_PATH", etc)
    cfg, source = load_config()
    assert cfg.hdr.method == "none" and source == str(etc)


def test_cross_check_reconnect_times() -> None:
    bad = {"device": {"reconnect_min_s": 5.0, "reconnect_max_s": 1.0}}
    with pytest.raises(ConfigError) as ei:
        parse_config(bad)
    assert "must be >= device.reconnect_min_s" in check_error(ei.value, "device.reconnect_max_s")
    with pytest.raises(ConfigError, match="reconnect_max_s"):
        apply_overrides(Config(), {"device.reconnect_min_s": 60.0})


def test_error_carries_key_value_and_allowed() -> None:
    with pytest.raises(ConfigError) as ei:
        parse_config({"hdr": {"tau": -1}}, source="/etc/hdrd/hdrd.yaml")
    e = ei.value
    assert (e.key, e.value, e.source) == ("hdr.tau", -1.0, "/etc/hdrd/hdrd.yaml")
    assert (
        str(e)
        == "config error in /etc/hdrd/hdrd.yaml: hdr.tau = -1.0: must be a finite number >= 0 and "
        "<= 3600"
    )
    assert isinstance(e, ValueError) and isinstance(e, HdrdError) and EX_CONFIG == 78


def test_values_and_keys_with_line_breaks_stay_on_one_line() -> None:
    for data, key in [
        ({"device": {"port": ["a\nb"]}}, "device.port"),
        ({"device": {"baud": {"k": "x" * 30 + "\n\n" + "y"}}}, "device.baud"),
        ({"device": {"a\nb": 1}}, "device.a\nb"),
        ({"log": {"level": "info\r\nwarning"}}, "log.level"),
    ]:
        with pytest.raises(ConfigError) as ei:
            parse_config(data)
        assert "\n" not in str(ei.value) and "\r" not in str(ei.value)
        assert ei.value.key == key


def test_long_values_are_shortened() -> None:
    with pytest.raises(ConfigError) as ei:
        parse_config({"device": {"baud": list(range(1000))}})
    assert len(str(ei.value)) < 200 and "..." in str(ei.value)


# -- apply_overrides ----------------------------------------------------------------------------


def test_apply_overrides() -> None:
    cfg = apply_overrides(
        Config(),
        {
            "device.port": "loop://",
            "hdr.method": "none",
            "hdr.i_c": 0.05,
            "output.udp": ("127.0.0.1:10110",),
            "output.heading0_deg": None,  # a flag not given: skipped
        },
    )
    assert cfg.device.port == "loop://" and cfg.hdr.method == "none"
    assert cfg.hdr.params == HdrParams(i_c=0.05)
    assert cfg.output.udp == ("127.0.0.1:10110",) and cfg.output.heading0_deg == 0.0
    # Overrides stack on a loaded config and keep what they do not touch.
    again = apply_overrides(cfg, {"hdr.tau": 1.0})
    assert again.hdr.params == HdrParams(i_c=0.05, tau=1.0) and again.hdr.method == "none"


@pytest.mark.parametrize("dotted", ["bogus.key", "device.bogus", "hdr.params", "device"])
def test_apply_overrides_unknown(dotted: str) -> None:
    with pytest.raises(ConfigError) as ei:
        apply_overrides(Config(), {dotted: 1})
    assert "unknown" in str(ei.value) and "\n" not in str(ei.value)


# -- numbers YAML 1.1 reads as text ------------------------------------------------------------


@pytest.mark.parametrize(
    "written, value",
    [("1e-2", 0.01), ("1.0e9", 1e9), ("5E-1", 0.5), ("+2e0", 2.0), (".5e1", 5.0), ("1.e1", 10.0)],
)
def test_exponent_numbers_yaml_reads_as_text_are_numbers(
    tmp_path: Path, written: str, value: float
) -> None:
    """PyYAML (YAML 1.1) reads 1e-2 and 1.0e9 as strings; they used to be refused with
    "must be a number". A number key takes them, as YAML 1.2 would."""
    assert isinstance(yaml.safe_load(f"x: {written}")["x"], str)  # what the parser gives
    f = tmp_path / "hdrd.yaml"
    f.write_text(f"gpsd:\n  bias_window_s: {written}\n  min_speed_mps: {written}\n")
    cfg, _ = load_config(f)
    assert cfg.gpsd.bias_window_s == value and type(cfg.gpsd.bias_window_s) is float
    assert cfg.gpsd.min_speed_mps == value


@pytest.mark.parametrize(
    "key, text, why",
    [
        ("hdr.tau", "1e", "must be a number"),
        ("hdr.tau", "e5", "must be a number"),
        ("hdr.tau", "1e-2 s", "must be a number"),
        ("hdr.tau", "1e999", "must be a finite number"),
        ("hdr.tau", "1e4", "hdr.tau = 10000.0: must be a finite number >= 0 and <= 3600"),
        ("device.baud", "1e6", "must be an integer, written out in digits"),
    ],
)
def test_text_that_is_no_number_is_still_refused(key: str, text: str, why: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(nested(key, text))
    assert why in str(e.value), str(e.value)
    assert "10000" in str(e.value) or f"{key} = '{text}'" in str(e.value), str(e.value)


# -- the shipped config/hdrd.yaml --------------------------------------------------------------


def test_shipped_config_equals_builtin_defaults() -> None:
    cfg, source = load_config(SHIPPED)
    assert cfg == Config()
    assert source == str(SHIPPED)


def test_shipped_config_names_every_key() -> None:
    data = yaml.safe_load(SHIPPED.read_text())
    written = {f"{s}.{k}" for s, sec in data.items() for k in sec}
    assert written == set(config_field_keys())


def test_shipped_config_comments_every_key() -> None:
    lines = SHIPPED.read_text().splitlines()
    seen = set()
    section = None
    for i, line in enumerate(lines):
        m = re.match(r"^(\w+):\s*$", line)
        if m:
            section = m.group(1)
            continue
        m = re.match(r"^  (\w+):", line)
        if m:
            key = f"{section}.{m.group(1)}"
            seen.add(key)
            assert lines[i - 1].lstrip().startswith("#"), f"{key} has no comment above it"
    assert seen == set(config_field_keys())


def test_shipped_config_cites_the_paper_values() -> None:
    text = SHIPPED.read_text()
    for cite in ("Table III: 0.0422", "Table III: 0.75", "Table III: 0.564", "Table III: 0.16",
                 "Table III: 1.80", "Ti = 1 sec", "Tbias = 30 seconds", "10 mV/(deg/s)",
                 "+/-200 deg/s", "10 Hz"):  # fmt: skip
        assert cite in text, cite


# -- fuzz: whatever YAML holds, the answer is a Config or a one-line ConfigError ------------------

names = st.sampled_from(
    [k.split(".")[1] for k in config_field_keys()] + ["bogus", "", "a\nb", "params"]
)
sections = st.sampled_from([f.name for f in fields(Config)] + ["bogus"])
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**30), 10**30), st.floats(), st.text(max_size=20)
)
values = st.recursive(
    scalars,
    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
    max_leaves=6,
)


@settings(deadline=None)
@given(
    data=st.one_of(
        values,
        st.dictionaries(
            sections, st.one_of(values, st.dictionaries(names, values, max_size=4)), max_size=4
        ),
    )
)
def test_fuzz_config_or_one_line_error(data: Any) -> None:
    try:
        cfg = parse_config(data, source="fuzz.yaml")
    except ConfigError as e:
        assert "\n" not in str(e) and str(e).startswith("config error in fuzz.yaml: ")
    else:
        assert isinstance(cfg, Config)


# -- parse_hostport ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, want",
    [
        ("127.0.0.1:10110", ("127.0.0.1", 10110)),
        ("[::1]:10110", ("::1", 10110)),
        (":10110", ("127.0.0.1", 10110)),
        ("gps.local:2947", ("gps.local", 2947)),
    ],
)
def test_parse_hostport(text: str, want: tuple[str, int]) -> None:
    assert parse_hostport(text) == want


@pytest.mark.parametrize(
    "text",
    ["localhost", "host:0", "host:65536", "host:", "host:x", "a b:1", 5, "[]:1", "[::1:7400"],
)
def test_parse_hostport_rejects(text: Any) -> None:
    with pytest.raises(ValueError):
        parse_hostport(text)


@pytest.mark.parametrize("text", ["::1:7400", "fe80::1:10110", "2001:db8::2:53"])
def test_an_ipv6_destination_needs_brackets(text: str) -> None:
    """'::1:7400' is the address ::1 port 7400, or the address ::1:7400 with no port: it used
    to be taken as the first. Refused, saying how to write it."""
    host, _, port = text.rpartition(":")
    with pytest.raises(ValueError, match=re.escape(f"in brackets: [{host}]:{port}")):
        parse_hostport(text)
    assert parse_hostport(f"[{host}]:{port}") == (host, int(port))
    with pytest.raises(ConfigError) as e:
        parse_config({"output": {"udp": ["127.0.0.1:10110", text]}})
    msg = check_error(e.value, "output.udp")
    assert f"{text!r} is not: an IPv6 address goes in brackets: [{host}]:{port}" in msg


# -- the CLI: exit 78 (EX_CONFIG) with the one line on stderr -----------------------------------

FIRST_BAD = [(k, bad[0]) for k, (_, bad) in TABLE.items()]


@pytest.mark.parametrize("key, value", FIRST_BAD, ids=[k for k, _ in FIRST_BAD])
def test_cli_exits_78_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], key: str, value: Any
) -> None:
    from hdrd.cli import main

    p = tmp_path / "hdrd.yaml"
    p.write_text(yaml.safe_dump(nested(key, value)))
    capture = tmp_path / "none.cap"  # never opened: the config is checked first
    assert main(["replay", str(capture), "--config", str(p)]) == 78
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"hdrd: config error in {p}: {key} = ")


@pytest.mark.parametrize("text", ["", "hdr: [\n", "bogus: 1\n"])
def test_cli_exits_78_on_file_level_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str
) -> None:
    from hdrd.cli import main

    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    assert main(["replay", str(tmp_path / "none.cap"), "--config", str(p)]) == 78
    assert len(capsys.readouterr().err.splitlines()) == 1
    assert (
        main(["replay", str(tmp_path / "none.cap"), "--config", str(tmp_path / "missing.yaml")])
        == 78
    )
    assert "no such file" in capsys.readouterr().err


DOCS = SHIPPED.parent.parent / "docs" / "configuration.md"


def docs_section(title: str) -> str:
    """The text of one `## title` section of docs/configuration.md."""
    text = DOCS.read_text()
    head = f"\n## {title}\n"
    assert head in text, f"docs/configuration.md has no section '## {title}'"
    return text.split(head, 1)[1].split("\n## ", 1)[0]


def docs_key_table() -> dict[str, list[str]]:
    """docs/configuration.md's key table: key -> its cells (default, unit, meaning, allowed,
    source)."""
    rows = re.findall(r"^\| `(\w+\.\w+)` \|(.*)\|$", docs_section("Keys"), flags=re.MULTILINE)
    table = {k: [c.strip() for c in rest.split(" | ")] for k, rest in rows}
    assert len(table) == len(rows), "a key appears twice in docs/configuration.md's key table"
    return table


def test_docs_config_table_matches_the_code() -> None:
    table = docs_key_table()
    assert set(table) == set(config_field_keys())
    for key, cells in table.items():
        value = yaml.safe_load(cells[0].strip("`"))
        default = get(Config(), key)
        assert (tuple(value) if isinstance(value, list) else value) == default, key


@pytest.mark.parametrize("method", ["none", "hdr", "hdr+"])
def test_top_level_method_is_hdr_method(tmp_path: Path, method: str) -> None:
    f = tmp_path / "hdrd.yaml"
    f.write_text(f"method: {method}\nhdr:\n  i_c: 0.03\n")
    cfg, _ = load_config(f)
    assert cfg.hdr.method == method and cfg.hdr.params.i_c == 0.03
    assert parse_config({"method": method}).hdr.method == method


@pytest.mark.parametrize(
    ("data", "why"),
    [
        ({"method": "hdr++"}, "must be one of none, hdr, hdr+"),
        ({"method": 1}, "must be one of none, hdr, hdr+"),
        ({"method": "hdr+", "hdr": {"method": "hdr"}}, "conflicts with hdr.method = 'hdr'"),
    ],
)
def test_top_level_method_errors_name_the_key(data: dict[str, Any], why: str) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(data)
    assert str(e.value).startswith("config error: method = ") and why in str(e.value)


# -- every numeric key at both ends of its range keeps every computation finite -----------------


def _edges(key: str) -> list[Any]:
    """The extreme values a numeric key accepts (an open end nudged one ulp inside)."""
    lo, hi, lo_open, hi_open = configload.RULES[key][0].bounds  # type: ignore[attr-defined]
    integer = isinstance(get(Config(), key), int) and not isinstance(get(Config(), key), bool)
    out: list[Any] = []
    for end, is_open, inward in ((lo, lo_open, math.inf), (hi, hi_open, -math.inf)):
        if end is None:
            continue
        if integer:
            out.append(int(end) + (0 if not is_open else (1 if inward > 0 else -1)))
        else:
            out.append(math.nextafter(float(end), inward) if is_open else float(end))
    return out


NUMERIC = [
    k
    for k, (check, _) in configload.RULES.items()
    if hasattr(check, "bounds") and not k.startswith("gpsd.")  # gpsd: tests/test_aiding.py
]
EDGES = [(k, v) for k in NUMERIC for v in _edges(k)]


def _hard_capture() -> bytes:
    """Two minutes at 10 Hz that drive every stage to its corners: rails (counts 0 and
    65535), a wired supply monitor at its extremes, a long same-sign stretch (the repetition
    counter grows), a clock jump of 20 s and a device clock wrap."""
    from hdrd.io.wire.capture import encode_array
    from hdrd.io.wire.codec import FRAME_DTYPE

    n = 1200
    arr = np.zeros(n, FRAME_DTYPE)
    arr["seq"] = np.arange(n) & 0xFFFF
    t = (np.arange(n, dtype=np.int64) * 100_000) + (2**32 - 30_000_000)  # wraps after 30 s
    t[600:] += 20_000_000  # 20 s without samples
    arr["t_us"] = t % 2**32
    rate = np.full(n, 32768)
    rate[200:400] = 65535  # saturated one way, then the other
    rate[400:450] = 0
    rate[450:900] = 32900  # a long gentle turn: one sign for 45 s
    arr["rate"] = rate
    ref = np.zeros(n, np.int64)
    ref[900:1000] = 1  # supply monitor wired, at its lowest and highest reading
    ref[1000:1100] = 65535
    arr["ref"] = ref
    arr["temp"] = np.where(np.arange(n) % 7 == 0, -32768, 2150)
    return encode_array(arr)


@pytest.mark.parametrize("key, value", EDGES, ids=[f"{k}={v!r}" for k, v in EDGES])
def test_every_key_at_its_edges_keeps_every_number_finite(key: str, value: Any) -> None:
    from hdrd.daemon.replay import replay_capture

    data = nested(key, value)
    if key.startswith("device.reconnect_"):  # the cross-check wants min <= max
        data = {"device": {"reconnect_min_s": value, "reconnect_max_s": value}}
    cfg = parse_config(data)
    capture = _hard_capture()
    for method in ("none", "hdr", "hdr+"):
        c = apply_overrides(cfg, {"hdr.method": method})
        for bias, startup in ((0.3, None), (None, None), (None, cfg.calibration.startup_s)):
            for msg in replay_capture(capture, c, bias, startup):
                for name, v in msg.items():
                    if isinstance(v, float):
                        assert math.isfinite(v), (key, value, method, name, msg)


def test_the_attenuator_stays_finite_for_any_run_length() -> None:
    # hdr.c2 <= 10 and hdr.c1 <= 1000: R(r) = (1 + c1) / (1 + c1 r^c2) is finite and > 0 for
    # any repetition count a run can reach (r < 2**63; 2**63**10 ~ 1e190).
    from hdrd.core.hdr import attenuation

    assert 0.0 < attenuation(2**63, c1=1000.0, c2=10.0) < 1.0
    assert attenuation(2**63, c1=0.0, c2=10.0) == 1.0


@pytest.mark.parametrize(
    "text, why",
    [
        ("hdr:\n  c2: " + "1" * 5000 + "\n", "line 2, column 7: YAML value cannot be converted"),
        ("a: " + "[" * 2000 + "]" * 2000 + "\n", "collections nested deeper than 32 levels"),
        ("x: " + "{a: " * 40 + "1" + "}" * 40 + "\n", "nested deeper than 32 levels"),
        ("calibration:\n  bias_file: 2024-13-45\n", "YAML value cannot be converted (month"),
    ],
)
def test_what_the_yaml_parser_cannot_take_is_a_config_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, why: str
) -> None:
    from hdrd.cli import main

    p = tmp_path / "hdrd.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert why in check_error(ei.value, "(yaml)", str(p))
    assert main(["replay", str(tmp_path / "none.cap"), "--config", str(p)]) == 78
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and why in err


def test_a_config_that_is_not_a_regular_file_or_too_big(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)  # would block the reader for ever
    for path, why in (
        (fifo, "is a FIFO, not a regular file"),
        (Path("/dev/zero"), "is a character device, not a regular file"),
        (tmp_path, "is a directory, not a regular file"),
    ):
        with pytest.raises(ConfigError) as ei:
            load_config(path)
        assert why in check_error(ei.value, "(file)", str(path))
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (1 << 20) + "\nhdr:\n  method: none\n")
    with pytest.raises(ConfigError) as ei:
        load_config(big)
    assert "larger than the 1 MiB allowed" in check_error(ei.value, "(file)", str(big))


def test_docs_state_the_ranges_the_code_checks() -> None:
    # The key table's allowed column words each numeric range and each list of choices as
    # the code does, and says "true or false" for the switches.
    table = docs_key_table()
    for key in config_field_keys():
        shown = table[key][3]
        rule = configload.RULES.get(key)
        if rule is None:
            if isinstance(get(Config(), key), bool):
                assert shown == "true or false", key
            continue
        check, wording = rule[0], rule[1]() if callable(rule[1]) else rule[1]
        if hasattr(check, "bounds"):
            words = wording.removeprefix("a finite number ")
            assert shown == (f"auto, or {words}" if key == "hdr.i_c" else words), key
        elif wording.startswith("one of "):
            assert shown == wording, key
    # ... and every bounded key says why its bound is where it is.
    why = docs_section("Why the ranges are where they are")
    shared = (
        "calibration.max_std_dps",
        "calibration.max_trend_dps",
        "calibration.max_excursion_dps",
    )
    for key, (check, _) in configload.RULES.items():
        if hasattr(check, "bounds") and not key.startswith("gpsd.") and key not in shared:
            assert f"| `{key}` |" in why, key
