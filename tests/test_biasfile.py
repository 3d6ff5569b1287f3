"""hdrd.io.files.biasfile: the bias file, a static bias record as YAML written atomically (mode
0644 whatever the umask, the old file whole if a write fails) and read back exactly, or
refused in one line naming the file and the problem (truncated, corrupted, not a regular
file, too large, a value no measurement gives, a bias beyond the configured limit).

The measurement the record holds: test_calibrate.py; the file as ``hdrd run`` and ``hdrd
calibrate`` meet it (power cuts, concurrent writers, a fallback to measuring):
test_rel_state.py; the atomic write itself: test_files.py.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hdrd.core.calibrate import BiasRecord
from hdrd.io.files import biasfile
from hdrd.io.files.biasfile import BiasFileError, load_bias, save_bias

REC = BiasRecord(
    bias_dps=0.8123456789012345,
    std_dps=0.0512,
    n=300,
    duration_s=29.9,
    temp_c=21.5,
    time=1_700_000_000.25,
)


def test_save_load_round_trip(tmp_path: Path) -> None:
    p = tmp_path / "state" / "bias.yaml"  # the directory is created
    save_bias(p, REC)
    assert load_bias(p) == REC
    text = p.read_text()
    assert text.startswith("# hdrd static bias") and text.endswith("# end\n")
    no_temp = BiasRecord(-0.25, 0.01, 10, 1.0, None, 0.0)
    save_bias(p, no_temp)
    assert load_bias(p) == no_temp


@settings(max_examples=50, deadline=None)
@given(
    bias=st.floats(-200, 200, allow_nan=False),
    std=st.floats(0, 10),
    n=st.integers(1, 10**7),
    temp=st.one_of(st.none(), st.floats(-40, 85)),
)
def test_round_trip_is_exact(
    tmp_path_factory: pytest.TempPathFactory, bias: float, std: float, n: int, temp: float | None
) -> None:
    p = tmp_path_factory.mktemp("rt") / "bias.yaml"
    rec = BiasRecord(bias, std, n, 30.0, temp, 1.5)
    save_bias(p, rec)
    assert load_bias(p) == rec


def test_file_mode_is_0644_whatever_the_umask(tmp_path: Path) -> None:
    p = tmp_path / "bias.yaml"
    p.write_text("old")
    os.chmod(p, 0o600)
    old = os.umask(0o077)
    try:
        save_bias(p, REC)
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o644


def _leftovers(d: Path) -> list[str]:
    return sorted(x.name for x in d.iterdir() if x.name != "bias.yaml")


@pytest.mark.parametrize("fail_in", ["replace", "fsync", "write"])
def test_failed_write_leaves_old_file_whole_and_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail_in: str
) -> None:
    p = tmp_path / "bias.yaml"
    save_bias(p, REC)
    before = p.read_bytes()

    def boom(*a: object, **k: object) -> None:
        raise OSError(28, "No space left on device")

    if fail_in == "replace":
        monkeypatch.setattr(biasfile.os, "replace", boom)
    elif fail_in == "fsync":
        monkeypatch.setattr(biasfile.os, "fsync", boom)
    else:
        real_fdopen = os.fdopen

        class HalfWriter:
            """A file object that writes half of the text, then fails (a power cut)."""

            def __init__(self, f):
                self.f = f

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                self.f.close()

            def write(self, text: str) -> None:
                self.f.write(text[: len(text) // 2])
                self.f.flush()
                raise OSError(5, "Input/output error")

        monkeypatch.setattr(
            biasfile.os, "fdopen", lambda fd, *a, **k: HalfWriter(real_fdopen(fd, *a, **k))
        )
    with pytest.raises(OSError):
        save_bias(p, BiasRecord(5.0, 0.1, 10, 1.0))
    assert p.read_bytes() == before
    assert load_bias(p) == REC
    assert _leftovers(tmp_path) == []


def test_interrupt_during_write_leaves_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # SIGTERM/Ctrl-C (a BaseException) between fsync and rename: the old file stays, no temp.
    p = tmp_path / "bias.yaml"
    save_bias(p, REC)

    def interrupted(*a: object, **k: object) -> None:  # os.replace(..., src_dir_fd=...)
        raise KeyboardInterrupt

    monkeypatch.setattr(biasfile.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_bias(p, BiasRecord(5.0, 0.1, 10, 1.0))
    assert load_bias(p) == REC and _leftovers(tmp_path) == []


def test_missing_bias_file(tmp_path: Path) -> None:
    p = tmp_path / "nope.yaml"
    with pytest.raises(BiasFileError, match=r"bias file .*nope\.yaml: not found"):
        load_bias(p)


def test_every_truncation_is_refused(tmp_path: Path) -> None:
    # A file cut anywhere (a power cut without atomic replace) never loads as a wrong bias.
    good = tmp_path / "good.yaml"
    save_bias(good, REC)
    data = good.read_bytes()
    p = tmp_path / "bias.yaml"
    for k in range(len(data.rstrip(b"\n"))):
        p.write_bytes(data[:k])
        with pytest.raises(BiasFileError, match="truncated"):
            load_bias(p)
    p.write_bytes(data.rstrip(b"\n"))  # only the final newline lost: still whole
    assert load_bias(p) == REC


def _body(**changes: object) -> str:
    d: dict[str, object] = {
        "bias_dps": 0.5,
        "std_dps": 0.05,
        "n": 300,
        "duration_s": 30.0,
        "temp_c": None,
        "time": 1.0,
    }
    d.update(changes)
    lines = [f"{k}: {'null' if v is None else v}" for k, v in d.items() if v is not ...]
    return "\n".join(lines) + "\n# end\n"


@pytest.mark.parametrize(
    "text, match",
    [
        (_body(bias_dps="abc"), r"bias_dps = 'abc' is not a finite number"),
        (_body(bias_dps=".nan"), r"bias_dps = nan is not a finite number"),
        (_body(bias_dps=".inf"), r"bias_dps = inf is not a finite number"),
        (_body(bias_dps="true"), r"bias_dps = True is not a finite number"),
        (_body(bias_dps=...), r"missing key bias_dps"),
        (_body(n=...), r"missing key n"),
        (_body(time=...), r"missing key time"),
        (_body(n="3.5"), r"n = 3.5 is not an integer"),
        (_body(n="true"), r"n = True is not an integer"),
        (_body(n='"300"'), r"n = '300' is not an integer"),
        (_body(n="0"), r"must not be negative"),
        (_body(std_dps="-0.1"), r"must not be negative"),
        (_body(temp_c="warm"), r"temp_c = 'warm' is not a finite number"),
        ("- 0.5\n- 0.1\n# end\n", r"expected a mapping"),
        ("bias_dps: [0.5\n# end\n", r"not valid YAML"),
        ("# end\n", r"expected a mapping"),
        # Values no measurement gives, which would overflow later (std**2 / n, float(n)).
        (_body(bias_dps="1" * 400), r"bias_dps = 1111.* is not a finite number"),
        (_body(std_dps="1.0e+308"), r"std_dps = 1e\+308 is beyond what a measurement gives"),
        (_body(n=str(10**13)), r"n = 10000000000000 .* is beyond what a measurement gives"),
        # What the YAML parser itself cannot take: one line, never a traceback.
        (_body(bias_dps="1" * 5000), r"not valid YAML at line 1, column 11: .*cannot be converted"),
        ("a: " + "[" * 2000 + "]" * 2000 + "\n# end\n", r"nested deeper than 32 levels"),
        (_body(time="2024-13-45"), r"not valid YAML at line 6.*month must be in 1\.\.12"),
    ],
)
def test_corrupted_bias_file(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "bias.yaml"
    p.write_text(text)
    with pytest.raises(BiasFileError, match=match) as e:
        load_bias(p)
    assert str(p) in str(e.value)
    assert "\n" not in str(e.value)


def test_binary_garbage_and_directory(tmp_path: Path) -> None:
    p = tmp_path / "bias.yaml"
    p.write_bytes(b"\xff\xfe\x00garbage\x80# end\n")
    with pytest.raises(BiasFileError, match="cannot be read"):
        load_bias(p)
    with pytest.raises(BiasFileError, match="cannot be read"):
        load_bias(tmp_path)


def test_a_bias_beyond_the_limit_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "bias.yaml"
    p.write_text(_body(bias_dps="1.0e+308"))
    assert load_bias(p).bias_dps == 1e308  # finite: the file format alone allows it
    for value, limit in (("1.0e+308", 3.0), ("3.5", 3.0), ("-3.5", 3.0)):
        p.write_text(_body(bias_dps=value))
        with pytest.raises(
            BiasFileError,
            match=rf"bias_dps = .* is beyond the \+/-{limit:g} deg/s "
            r"allowed \(calibration\.max_bias_dps\)",
        ):
            load_bias(p, max_abs_bias_dps=limit)
    p.write_text(_body(bias_dps="-2.5"))
    assert load_bias(p, max_abs_bias_dps=3.0).bias_dps == -2.5


def test_not_a_regular_file_is_refused_at_once(tmp_path: Path) -> None:
    # A FIFO would block the reader until a writer came; /dev/zero never ends.
    fifo = tmp_path / "bias.yaml"
    os.mkfifo(fifo)
    with pytest.raises(BiasFileError, match=r"cannot be read: is a FIFO, not a regular file"):
        load_bias(fifo)
    with pytest.raises(BiasFileError, match=r"is a character device, not a regular file"):
        load_bias("/dev/zero")
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (64 << 10) + "\n" + _body())
    with pytest.raises(BiasFileError, match=r"is 64\.\d KiB, larger than the 64 KiB allowed"):
        load_bias(big)


def test_a_well_formed_body_loads(tmp_path: Path) -> None:
    # The hand-written form above is accepted as it is: the corruption tests do test corruption.
    p = tmp_path / "bias.yaml"
    p.write_text(_body())
    assert load_bias(p) == BiasRecord(0.5, 0.05, 300, 30.0, None, 1.0)


def test_a_bias_file_records_noise_parameters_and_older_files_still_read(tmp_path: Path) -> None:
    from hdrd.core.gyronoise import GyroNoise

    noise = GyroNoise(white_dps_per_rthz=0.05, rrw_dps_per_sqrt_s=3e-4, quant_step_dps=0.0076)
    p = tmp_path / "bias.yaml"
    save_bias(p, BiasRecord(0.5, 0.1, 300, 30.0, None, 1.0, noise))
    got = load_bias(p)
    assert got.noise is not None and got.noise.source == "recorded" and got.noise.known()
    assert got.noise.to_dict() == noise.to_dict()
    # a file written before noise parameters were recorded: read, no noise
    old = tmp_path / "old.yaml"
    old.write_text("bias_dps: 0.5\nstd_dps: 0.1\nn: 300\nduration_s: 30.0\ntemp_c: null\n"
                   "time: 1.0\n# end\n")  # fmt: skip
    assert load_bias(old) == BiasRecord(0.5, 0.1, 300, 30.0, None, 1.0)
    for bad, why in (
        ("noise: 3\n", "noise must be a mapping"),
        ("noise:\n  white: 0.1\n", "unknown noise parameter 'white'"),
        ("noise:\n  rrw_dps_per_sqrt_s: -1\n", "rrw_dps_per_sqrt_s = -1"),
    ):
        f = tmp_path / "bad.yaml"
        f.write_text(old.read_text().replace("# end", bad + "# end"))
        with pytest.raises(BiasFileError, match=why):
            load_bias(f)
