"""hdrd.io.files.access: reading the files hdrd is handed without trusting them (a regular file
within a size limit, refused at once otherwise; YAML through the safe loader with its nesting
bounded, every parser failure one InputFileError), writing its own atomically (whole or not
at all, stale temporary files of dead writers cleaned, a live writer's left alone), and names
from data made paths only inside the output folder.

The bias file on top of these: test_biasfile.py; hostile YAML through the configuration and
the commands: test_hardening.py, test_config.py; names from data through ``hdrd gap``,
``simulate`` and ``convert``: test_drive_names.py.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from hdrd.io.files.access import (
    MAX_NAME_BYTES,
    MAX_SHOWN_PATH,
    MAX_YAML_DEPTH,
    InputFileError,
    OutputFileError,
    UnsafeNameError,
    atomic_output,
    atomic_write_json,
    atomic_write_text,
    default_bias_path,
    load_yaml,
    missing_folder,
    path_inside,
    printable,
    read_limited,
    shown_path,
)


def temps(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp"))


# -- reading -------------------------------------------------------------------------------


def test_read_limited_reads_a_file_up_to_its_limit_exactly(tmp_path: Path) -> None:
    p = tmp_path / "f"
    p.write_bytes(b"x" * 1000)
    assert read_limited(p, 1000) == b"x" * 1000
    with pytest.raises(InputFileError, match="is 1000 bytes, larger than the 999 bytes allowed"):
        read_limited(p, 999)
    p.write_bytes(b"")
    assert read_limited(p, 0) == b""


def test_read_limited_says_sizes_in_binary_units(tmp_path: Path) -> None:
    p = tmp_path / "f"
    p.write_bytes(b"\0" * (3 << 20))
    with pytest.raises(InputFileError, match=r"is 3 MiB, larger than the 1 MiB allowed"):
        read_limited(p, 1 << 20)


def test_read_limited_refuses_what_is_not_a_regular_file_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # no writer: a blocking open would wait for ever
    with pytest.raises(InputFileError, match="^is a FIFO, not a regular file$"):
        read_limited(fifo, 100)
    with pytest.raises(InputFileError, match="^is a directory, not a regular file$"):
        read_limited(tmp_path, 100)
    with pytest.raises(InputFileError, match="^is a character device, not a regular file$"):
        read_limited("/dev/zero", 100)  # would never end
    with pytest.raises(FileNotFoundError):
        read_limited(tmp_path / "missing", 100)


def test_read_limited_follows_a_link_to_a_regular_file(tmp_path: Path) -> None:
    (tmp_path / "real").write_text("body")
    (tmp_path / "link").symlink_to(tmp_path / "real")
    assert read_limited(tmp_path / "link", 10) == b"body"


def test_load_yaml_is_the_safe_loader() -> None:
    assert load_yaml("a: 1\nb: [x, 2.5, null]\n") == {"a": 1, "b": ["x", 2.5, None]}
    assert load_yaml("") is None
    with pytest.raises(InputFileError, match="could not determine a constructor"):
        load_yaml("!!python/object/apply:os.system ['true']\n")


def test_load_yaml_bounds_the_nesting() -> None:
    ok = "[" * MAX_YAML_DEPTH + "]" * MAX_YAML_DEPTH
    assert load_yaml(ok) is not None
    deep = "[" * (MAX_YAML_DEPTH + 1) + "]" * (MAX_YAML_DEPTH + 1)
    with pytest.raises(InputFileError, match=f"nested deeper than {MAX_YAML_DEPTH} levels") as e:
        load_yaml(deep)
    assert e.value.where == f"line 1, column {MAX_YAML_DEPTH + 1}"
    with pytest.raises(InputFileError, match="nested deeper"):
        load_yaml("a: " + "[" * 100_000)  # far past the recursion limit: still one error


def test_load_yaml_syntax_and_conversion_errors_say_where() -> None:
    with pytest.raises(InputFileError, match="^YAML syntax error: ") as e:
        load_yaml("a: [1, 2\nb: 3\n")
    assert e.value.where is not None and e.value.where.startswith("line ")
    with pytest.raises(InputFileError, match=r"value cannot be converted .*month") as e:
        load_yaml("when: 2024-13-45\n")
    assert e.value.where == "line 1, column 7"


@pytest.mark.parametrize("char", ["\x00", "\x1b", "\x07", "\ufffe"])
def test_yaml_with_a_control_character_is_one_input_error(char: str) -> None:
    with pytest.raises(InputFileError) as ei:
        load_yaml(f"hdr:\n  method: a{char}b\n")
    assert f"#x{ord(char):04x}" in str(ei.value)
    assert ei.value.where == "line 2, column 12"


# -- writing -------------------------------------------------------------------------------


def test_atomic_write_makes_the_folder_and_sets_the_mode_whatever_the_umask(
    tmp_path: Path,
) -> None:
    p = tmp_path / "a" / "b" / "out.txt"
    old = os.umask(0o077)
    try:
        atomic_write_text(p, "first\n")
        atomic_write_text(tmp_path / "private", "x", mode=0o600)
    finally:
        os.umask(old)
    assert p.read_text() == "first\n" and stat.S_IMODE(p.stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "private").stat().st_mode) == 0o600
    atomic_write_text(p, "second\n")
    assert p.read_text() == "second\n" and temps(p.parent) == []


def test_atomic_write_json_is_indented_with_a_final_newline(tmp_path: Path) -> None:
    p = tmp_path / "r.json"
    atomic_write_json(p, {"a": [1, 2.5], "b": None})
    text = p.read_text()
    assert text.endswith("}\n") and "\n  " in text
    assert json.loads(text) == {"a": [1, 2.5], "b": None}


def test_a_failed_write_leaves_the_old_file_and_no_temporary_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p = tmp_path / "out.txt"
    atomic_write_text(p, "old")

    def full(*a: object, **k: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space left"):
        atomic_write_text(p, "new")
    monkeypatch.undo()
    assert p.read_text() == "old" and temps(tmp_path) == []


def test_only_the_temporary_files_of_dead_writers_are_removed(tmp_path: Path) -> None:
    """A temp file names its writer's pid and is flocked by it until renamed: one whose
    writer is gone is removed by the next write, a live (or locking) writer's is not, and
    other files beside the target are never touched."""
    target = tmp_path / "out.txt"
    done = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, check=True
    )
    dead = int(done.stdout)  # a pid that ran and is gone (reuse within the test: unlikely)
    dead_one = tmp_path / f".out.txt.{dead}.aaaa.tmp"
    mine = tmp_path / f".out.txt.{os.getpid()}.bbbb.tmp"  # a live pid: this process
    locked = tmp_path / f".out.txt.{dead}.cccc.tmp"
    no_pid = tmp_path / ".out.txt.dddd.tmp"
    other = tmp_path / ".other.txt.1.eeee.tmp"
    for f in (dead_one, mine, locked, no_pid, other):
        f.write_text("partial")
    with locked.open() as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)  # a writer in another pid namespace
        atomic_write_text(target, "x")
        assert temps(tmp_path) == sorted([mine.name, locked.name, other.name])
    atomic_write_text(target, "y")
    assert temps(tmp_path) == sorted([mine.name, other.name])
    assert target.read_text() == "y"


def char_device(path: Path) -> Path:
    """A character device node at *path* with /dev/null's numbers (1, 3), made with mknod; the
    test is skipped, saying why, where mknod is not allowed."""
    if os.geteuid() != 0:
        pytest.skip("mknod of a character device needs root (CAP_MKNOD); run as root to test it")
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError as e:
        pytest.skip(f"mknod refused here (a container without CAP_MKNOD?): {e}")
    return path


def test_a_character_device_is_written_through_never_replaced(tmp_path: Path) -> None:
    # Was: the rename put a regular file in the device's place (as root: /dev/null's).
    node = char_device(tmp_path / "mynull")
    before = node.stat()
    atomic_write_json(node, {"a": 1})
    atomic_write_text(node, "x" * 100_000)
    after = node.stat()
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == os.makedev(1, 3)
    assert after.st_ino == before.st_ino and temps(tmp_path) == []


def test_dev_null_stays_the_systems(tmp_path: Path) -> None:
    if os.geteuid() == 0:
        pytest.skip("as root a defect here would replace the system's /dev/null: the node made "
                    "with mknod tests it instead")  # fmt: skip
    before = os.stat("/dev/null")
    atomic_write_json("/dev/null", {"a": 1})  # as a user, a rename into /dev would fail
    assert os.stat("/dev/null").st_ino == before.st_ino


def test_a_fifo_is_written_through_to_its_reader(tmp_path: Path) -> None:
    import threading

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    atomic_write_json(fifo, {"steps": list(range(20_000))})  # more than a pipe's buffer
    reader.join(30)
    assert json.loads(got[0]) == {"steps": list(range(20_000))}
    assert stat.S_ISFIFO(fifo.stat().st_mode) and temps(tmp_path) == []


def test_evaluate_json_to_a_device_leaves_the_device(tmp_path: Path) -> None:
    from hdrd.cli import main
    from hdrd.io.files.drivelog import write_drive
    from hdrd.sim import simulate_drive

    node = char_device(tmp_path / "mynull")
    drive = tmp_path / "d.csv"
    write_drive(drive, simulate_drive("city", 2.0, seed=3))
    assert main(["evaluate", str(drive), "--json", str(node), "--no-progress"]) == 0
    assert stat.S_ISCHR(node.stat().st_mode) and temps(tmp_path) == []


def test_a_directory_a_socket_or_a_block_device_is_refused(tmp_path: Path) -> None:
    import socket

    (tmp_path / "dir").mkdir()
    sock_path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.bind(str(sock_path))
        targets = {tmp_path / "dir": "a directory", sock_path: "a socket"}
        if os.geteuid() == 0:  # a node of the loop device: refused before anything is opened
            with contextlib.suppress(PermissionError):
                os.mknod(tmp_path / "disk", stat.S_IFBLK | 0o600, os.makedev(7, 0))
                targets[tmp_path / "disk"] = "a block device"
        for target, kind in targets.items():
            with pytest.raises(OutputFileError, match=f"is {kind}: only a regular file"):
                atomic_write_text(target, "x")
            assert not stat.S_ISREG(target.lstat().st_mode)
    assert temps(tmp_path) == []


def test_a_link_to_a_file_keeps_the_link_and_replaces_the_file(tmp_path: Path) -> None:
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    atomic_write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"


def test_an_output_is_made_only_in_a_folder_that_exists(tmp_path: Path) -> None:
    out = tmp_path / "no" / "x.csv"
    assert missing_folder(out) == f"the folder {tmp_path / 'no'} does not exist"
    assert missing_folder(tmp_path / "x.csv") is None
    with pytest.raises(OutputFileError, match="the folder .*/no does not exist"):
        with atomic_output(out) as f:
            f.write(b"x")
    assert not (tmp_path / "no").exists()
    with atomic_output(tmp_path / "x.bin") as f:  # and a failed block leaves nothing
        f.write(b"whole")
    with pytest.raises(RuntimeError), atomic_output(tmp_path / "x.bin") as f:
        f.write(b"half")
        raise RuntimeError
    assert (tmp_path / "x.bin").read_bytes() == b"whole" and temps(tmp_path) == []


def test_default_bias_path_is_the_units_state_directory(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/hdrd-x:/var/lib/other")
    assert default_bias_path() == Path("/var/lib/hdrd-x/bias.yaml")  # the first one
    monkeypatch.delenv("STATE_DIRECTORY")
    assert default_bias_path() == Path("/var/lib/hdrd/bias.yaml")
    monkeypatch.setenv("STATE_DIRECTORY", "")
    assert default_bias_path() == Path("/var/lib/hdrd/bias.yaml")


# -- names from data ------------------------------------------------------------------------


def test_printable_escapes_what_a_terminal_would_act_on() -> None:
    assert printable("drive05 é") == "drive05 é"
    assert printable("a\x1b[2Jb\n") == "a\\x1b[2Jb\\n"
    assert printable("\u202eevil") == "\\u202eevil"


def test_shown_path_keeps_the_end_of_a_long_path() -> None:
    assert shown_path("/tmp/a\x07b") == "/tmp/a\\x07b"
    long = "/data/" + "d" * 300 + "/drive05.csv"
    shown = shown_path(long)
    assert len(shown) == MAX_SHOWN_PATH and shown.startswith("...")
    assert shown.endswith("/drive05.csv") and long.endswith(shown[3:])
    assert shown_path(Path("/x/y")) == "/x/y"


@pytest.mark.parametrize(
    "name",
    ["", "/abs/x", "../../x", "a/../../x", "a/./b", "a//b", "a/", "..", ".", "a\x00b", "a\nb",
     "x" * (MAX_NAME_BYTES + 1), "é" * (MAX_NAME_BYTES // 2 + 1)],
)  # fmt: skip
def test_path_inside_refuses_a_name_that_could_lead_out(tmp_path: Path, name: str) -> None:
    with pytest.raises(UnsafeNameError) as e:
        path_inside(tmp_path, name, ".yaml")
    msg = str(e.value)
    assert "\n" not in msg and "\x00" not in msg and msg.isprintable()
    assert "cannot name a file inside" in msg


def test_path_inside_keeps_folders_of_a_name_inside(tmp_path: Path) -> None:
    assert path_inside(tmp_path, "phone/drive05", ".yaml") == tmp_path / "phone/drive05.yaml"
    assert path_inside(tmp_path, "a..b", "") == tmp_path / "a..b"
    assert path_inside(tmp_path, "x" * MAX_NAME_BYTES) == tmp_path / ("x" * MAX_NAME_BYTES)


def test_path_inside_refuses_a_symbolic_link_out_of_the_folder(tmp_path: Path) -> None:
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "etc").symlink_to(elsewhere)
    with pytest.raises(UnsafeNameError, match="symbolic link"):
        path_inside(out, "etc/hdrd", ".yaml")
    (out / "inner").mkdir()
    (out / "in").symlink_to(out / "inner")
    assert path_inside(out, "in/x", ".yaml") == out / "in" / "x.yaml"
