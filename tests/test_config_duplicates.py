"""A key given twice in one YAML mapping is refused, naming the key and both lines: YAML
keeps the last silently (``hdr: {method: hdr+, method: none}`` ran ``none``; of two ``hdr:``
sections the first was dropped). The configuration (exit 78), the bias file (exit 1, as any
refused bias file) and a gyro error model."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from hdrd.config import ConfigError
from hdrd.configload import load_config
from hdrd.errors import EX_CONFIG
from hdrd.io.files.biasfile import BiasFileError, load_bias

WAIT = 60.0


def hdrd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hdrd", *args], capture_output=True, text=True, timeout=WAIT
    )


@pytest.mark.parametrize(
    "text, key, lines",
    [
        ("hdr: {method: hdr+, method: none}\n", "hdr.method", (1, 1)),
        ("hdr:\n  method: hdr+\n  tau: 0.5\n  method: none\n", "hdr.method", (2, 4)),
        ("hdr:\n  method: hdr+\noutput:\n  stdout: true\nhdr:\n  tau: 0.5\n", "hdr", (1, 5)),
        ("gpsd:\n  enabled: true\n  host: a\n  'host': b\n", "gpsd.host", (3, 4)),
    ],
)
def test_hdrd_run_refuses_a_key_given_twice(
    tmp_path: Path, text: str, key: str, lines: tuple[int, int]
) -> None:
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(text)
    r = hdrd("run", "--config", str(cfg), "--port", str(tmp_path / "no-such-port"))
    assert r.returncode == EX_CONFIG, r.stderr
    err = r.stderr.splitlines()
    assert len(err) == 1 and r.stdout == ""
    assert err[0].startswith(f"hdrd: config error in {cfg}: {key} = ")
    assert f"line {lines[0]} and line {lines[1]}" in err[0] and "twice" in err[0]


def test_a_merge_key_and_anchors_are_not_duplicates(tmp_path: Path) -> None:
    """YAML's merge key overrides on purpose; an alias repeats a node, not a key."""
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(
        "calibration: &cal\n  max_std_dps: 0.4\n"
        "hdr:\n  <<: {tau: 0.5, c1: 0.2}\n  tau: 0.6\n"
        "output: {udp: &dst ['127.0.0.1:10110'], nmea_udp: *dst}\n"
    )
    c, _ = load_config(cfg)
    assert c.hdr.params.tau == 0.6 and c.hdr.params.c1 == 0.2
    assert c.output.nmea_udp == c.output.udp == ("127.0.0.1:10110",)


def test_aliases_are_walked_once(tmp_path: Path) -> None:
    """Nested aliases (a billion laughs) are a graph of a few nodes: the check walks each node
    once, and a duplicate deep inside is still found."""
    lines = ["a0: &a0 {x: 1, y: 2}"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 12)]
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError, match="unknown section"):
        load_config(cfg)
    cfg.write_text("\n".join(lines) + "\nlast: {deep: [{k: 1, k: 2}]}\n")
    with pytest.raises(ConfigError) as e:
        load_config(cfg)
    assert e.value.key == "last.deep[0].k" and "line 13 and line 13" in str(e.value)


def test_a_bias_file_with_a_key_given_twice_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "bias.yaml"
    f.write_text("bias_dps: 0.2\nstd_dps: 0.01\nn: 100\nduration_s: 10.0\ntime: 1.0\n"
                 "bias_dps: 2.5\n# end\n")  # fmt: skip
    with pytest.raises(BiasFileError, match=r"bias_dps given twice \(line 1 and line 6\)"):
        load_bias(f)
    cfg = tmp_path / "hdrd.yaml"
    cfg.write_text(f"calibration:\n  bias_file: {f}\n")
    r = hdrd("run", "--config", str(cfg), "--port", str(tmp_path / "no-such-port"))
    assert r.returncode == 1 and "bias_dps given twice (line 1 and line 6)" in r.stderr


def test_a_gyro_model_with_a_key_given_twice_is_refused(tmp_path: Path) -> None:
    from hdrd.sim.gyro import load_model

    f = tmp_path / "model.yaml"
    f.write_text("effects:\n  - {name: white_noise, density_dps_per_rthz: 0.01,"
                 " density_dps_per_rthz: 5.0}\n")  # fmt: skip
    with pytest.raises(ValueError, match=r"density_dps_per_rthz given twice \(line 2 and line 2\)"):
        load_model(f)
