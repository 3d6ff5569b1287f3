"""hdrd's files: reading the ones it is handed without trusting them, writing its own atomically.

Reading: a file must be a regular file (a FIFO would block the reader forever, ``/dev/zero``
never ends) no larger than a limit that fits its kind (:func:`read_limited`); YAML is parsed
with PyYAML's safe loader, its nesting depth bounded, and any failure of the parser (syntax,
a number with more digits than Python converts, an impossible date) becomes one
:class:`InputFileError` (:func:`load_yaml`). Callers turn that into their own one-line error
(:class:`hdrd.config.ConfigError`, :class:`hdrd.io.files.biasfile.BiasFileError`, the capture
commands' message).

Writing: the bias file, the ``--json``/``--out``/``--report`` files of evaluate, tune and
gap, and drive logs are written whole or not at all (:func:`atomic_output`,
:func:`atomic_write_text`, :func:`atomic_write_json`), so a reader or a power cut sees the old
or the new content. A character device or a FIFO named as the output (``/dev/null``,
``/dev/stdout``, a named pipe) is written through, never replaced by a regular file; a
directory, a block device or a socket is refused (:class:`OutputFileError`). A file hdrd
names itself in a folder the user named (a drive's trace, a benchmark's drive log, a dataset's
partition, a drive's fitted model: ``atomic_output(..., inside=FOLDER)``) replaces only a
regular file, and no folder on its way leads out of FOLDER: a symbolic link or a FIFO planted
there is refused, never written through. :func:`default_bias_path` is where the bias file
lives when none is named. A name that comes from data (a drive's name: a
Parquet ``drive`` value, a hive folder ``drive=NAME``) becomes a path only through
:func:`path_inside`, which refuses any name that would lead out of the output folder.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from hdrd.errors import HdrdError, clipped

__all__ = [
    "MAX_BIAS_BYTES",
    "MAX_CAPTURE_BYTES",
    "MAX_CONFIG_BYTES",
    "MAX_NAME_BYTES",
    "MAX_YAML_DEPTH",
    "InputFileError",
    "OutputFileError",
    "UnsafeNameError",
    "atomic_output",
    "atomic_write_json",
    "atomic_write_text",
    "default_bias_path",
    "load_yaml",
    "missing_folder",
    "path_inside",
    "printable",
    "read_limited",
    "shown_path",
    "size_text",
]

MAX_CONFIG_BYTES = 1 << 20
"""A configuration file: 1 MiB (the shipped one, every key with its comment, is ~10 KB)."""
MAX_BIAS_BYTES = 64 << 10
"""A bias file: 64 KiB (``hdrd calibrate`` writes ~250 bytes)."""
MAX_CAPTURE_BYTES = 2 << 30
"""A capture for ``hdrd replay``/``convert``: 2 GiB, 1.5 days of a 115200-baud link and
134 million hdr-bin frames; replay holds the file and its frames in memory (bench/RESULTS.md)."""
MAX_YAML_DEPTH = 32
"""Deepest nesting of YAML collections accepted (hdrd's files need 3)."""
MAX_NAME_BYTES = 200
"""Longest name from data that :func:`path_inside` turns into a path, UTF-8 bytes (a file
name may take 255; the suffix and a temporary file's decoration need the rest)."""

_KINDS = (
    (stat.S_ISLNK, "a symbolic link"),
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class InputFileError(HdrdError, ValueError):
    """A file that cannot be taken. ``str()`` is the problem, without the path; ``where``
    is "line L, column C" for a YAML problem that has a position, else None."""

    def __init__(self, problem: str, where: str | None = None) -> None:
        super().__init__(problem)
        self.problem = problem
        self.where = where


def read_limited(path: str | os.PathLike[str], max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``.

    Raises FileNotFoundError if there is no such file, InputFileError if it is not a regular
    file or is too large, OSError if it cannot be read. Opened non-blocking, so a FIFO is
    refused at once instead of waiting for a writer.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputFileError(f"is {_kind(st.st_mode)}, not a regular file")
        if st.st_size > max_bytes:
            raise InputFileError(
                f"is {size_text(st.st_size)}, larger than the {size_text(max_bytes)} allowed"
            )
        chunks: list[bytes] = []
        got = 0
        while True:  # to the end, as it is now: a file still growing stops at the limit
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - got))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
            if got > max_bytes:
                raise InputFileError(f"grew beyond the {size_text(max_bytes)} allowed while read")
        return b"".join(chunks)
    finally:
        os.close(fd)


def size_text(n: int) -> str:
    """A size in bytes for a message: ``1.5 GiB``, ``64 KiB``, ``300 bytes``."""
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << shift:
            return f"{n / (1 << shift):.3g} {unit}"
    return f"{n} bytes"


MAX_PROBLEM_CHARS = 160
"""Longest YAML problem text quoted in an error: PyYAML quotes the offending text (an
unknown tag of any length) and the error must stay one readable line."""


def load_yaml(text: str) -> Any:
    """``yaml.safe_load`` of a document whose collections nest at most MAX_YAML_DEPTH deep.

    Any problem (syntax, depth, a number of more digits than Python converts, an invalid
    timestamp, a tag the safe loader refuses) raises InputFileError naming it.
    """
    import yaml  # here, not at the top: hdrd run without a file never needs it (~18 ms)

    loader = None
    try:
        # The reader checks every character on construction: a control character anywhere
        # (NUL, ESC) is a ReaderError here, before any parsing.
        loader = _bounded_loader(yaml)(text)
        return loader.get_single_data()
    except yaml.reader.ReaderError as e:
        ch = e.character
        shown = f"#x{ch:04x}" if isinstance(ch, int) else repr(ch)
        raise InputFileError(
            f"YAML does not allow the character {shown} (a control or special character)",
            _line_column(text, e.position),
        ) from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else None
        problem = clipped(getattr(e, "problem", None) or "syntax error", MAX_PROBLEM_CHARS)
        if problem.startswith(("collections nested", "value cannot")):
            raise InputFileError(f"YAML {problem}", where) from None
        raise InputFileError(f"YAML syntax error: {problem}", where) from None
    except RecursionError:  # a guard: the depth bound should come first
        raise InputFileError(
            f"YAML collections nested deeper than {MAX_YAML_DEPTH} levels"
        ) from None
    except Exception as e:  # noqa: BLE001 - a guard, as construct_object's
        raise InputFileError(f"YAML value cannot be converted ({type(e).__name__})") from None
    finally:
        if loader is not None:
            loader.dispose()


def _line_column(text: str, position: int) -> str:
    """The 1-based "line L, column C" of a character offset in *text*."""
    line = text.count("\n", 0, position) + 1
    return f"line {line}, column {position - (text.rfind(chr(10), 0, position) + 1) + 1}"


_LOADER: Any = None


def _bounded_loader(yaml: Any) -> Any:
    """SafeLoader that refuses collections nested deeper than MAX_YAML_DEPTH (before the
    recursive composer and constructor could exhaust Python's stack)."""
    global _LOADER
    if _LOADER is not None:
        return _LOADER

    class BoundedSafeLoader(yaml.SafeLoader):
        _depth = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            self._depth += 1
            try:
                if self._depth > MAX_YAML_DEPTH:
                    mark = self.peek_event().start_mark
                    raise yaml.composer.ComposerError(
                        None, None, f"collections nested deeper than {MAX_YAML_DEPTH} levels", mark
                    )
                return super().compose_node(parent, index)
            finally:
                self._depth -= 1

        def construct_object(self, node: Any, deep: bool = False) -> Any:
            try:
                return super().construct_object(node, deep)
            except yaml.YAMLError:
                raise
            except Exception as e:  # noqa: BLE001 - PyYAML's constructors on hostile text
                # int() beyond sys.get_int_max_str_digits(), a date like 2024-13-45,
                # AttributeError for `!!timestamp 'not a time'`, ...
                if isinstance(e, (ValueError, OverflowError)):
                    why = (str(e).splitlines() or [type(e).__name__])[0]
                    why = clipped(why, 80)
                else:  # a message about PyYAML's insides: say what the text is not
                    why = f"not a valid {str(node.tag).rsplit(':', 1)[-1][:40]}"
                raise yaml.constructor.ConstructorError(
                    None, None, f"value cannot be converted ({why})", node.start_mark
                ) from None

    _LOADER = BoundedSafeLoader
    return _LOADER


# -- writing ----------------------------------------------------------------------------------


def _writer_alive(pid: int) -> bool:
    """Whether process ``pid`` (a temp file's writer, from its name) still runs."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: another user's process, alive
        return True
    return True


def _remove_stale_temps(folder: int, name: str) -> None:
    """Remove the temp files of writers to ``name`` in the open folder ``folder`` that died
    before their rename (killed, or a power cut). A temp file is another writer's work in
    progress while that writer lives: its name holds the writer's pid, and the writer holds an
    exclusive flock on it from its creation to its rename; such a file is left alone.
    (Removing every temp file, as was done, made a concurrent writer's rename fail: "No such
    file or directory".)"""
    prefix = f".{name}."
    for stale in os.listdir(folder):
        if not (stale.startswith(prefix) and stale.endswith(".tmp")):
            continue
        pid = stale[len(prefix) :].split(".", 1)[0]
        if pid.isdigit() and _writer_alive(int(pid)):
            continue
        try:
            fd = os.open(stale, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW, dir_fd=folder)
        except OSError:
            continue  # gone already, or not ours to open
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held: a live writer's
            os.unlink(stale, dir_fd=folder)
        except OSError:
            pass  # not ours to insist on; at worst one more leftover
        finally:
            os.close(fd)


class OutputFileError(HdrdError, OSError):
    """A file that cannot be written where it is named: ``str()`` says why (its folder does
    not exist; a directory, a block device or a socket is there; in a folder the user named,
    anything but a regular file, or a way out of the folder)."""


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike[str],
    mode: int = 0o644,
    make_parents: bool = False,
    inside: str | os.PathLike[str] | None = None,
) -> Iterator[IO[bytes]]:
    """A binary file to write ``path`` through, so that a reader (or a power cut) sees the old
    or the new content, whole. What ``path`` is decides how:

    - nothing, or a regular file (a symbolic link: the file it names, the link kept): a temp
      file in the same directory (``.NAME.PID.RANDOM.tmp``, unique, flocked by its writer
      until renamed), fsync'd, chmod'ed to ``mode`` and renamed over the target when the
      ``with`` block ends without an exception (removed if it raises); then the directory is
      fsync'd. Temp files that an earlier writer left behind (killed, or a power cut, before
      its rename) are removed first, so they never pile up; a live concurrent writer's is
      left alone, so writers may run at once (the last rename wins, each file whole);
    - a character device or a FIFO (``/dev/null``, ``/dev/stdout``, a named pipe): written
      through, as a shell's ``>`` does, never replaced (a rename would put a regular file in
      the device's place: as root, ``/dev/null``'s); a FIFO waits for its reader;
    - a directory, a block device or a socket: :class:`OutputFileError`, nothing written.

    The folder must exist (:class:`OutputFileError` naming it), unless ``make_parents``.

    ``inside``: ``path`` is a file hdrd names in a folder the user named (a drive's trace, a
    benchmark's drive log, a dataset's partition, a drive's fitted model), not a file the user
    named: only nothing or a regular file there is replaced (a symbolic link, a FIFO, a device
    or a directory is :class:`OutputFileError`, never written through or followed), and the
    folders on the way are made where missing but must stay inside ``inside`` (a symbolic
    link that leads out of it is :class:`OutputFileError`, nothing made outside).
    """
    if inside is not None:
        with _replace_in(_folder_inside(inside, path), Path(path).name, mode, path) as f:
            yield f
        return
    try:
        st: os.stat_result | None = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        st = None
    if st is not None and (stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode)):
        with open(path, "wb") as through:
            yield through
        return
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputFileError(
            f"is {_kind(st.st_mode)}: only a regular file (replaced whole), a character device "
            "or a FIFO (written through) is written"
        )
    target = Path(os.path.realpath(path))
    if make_parents:
        target.parent.mkdir(parents=True, exist_ok=True)
    elif (missing := missing_folder(target)) is not None:
        raise OutputFileError(missing)
    folder = os.open(target.parent, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    with _replace_in(folder, target.name, mode) as f:
        yield f


@contextlib.contextmanager
def _replace_in(
    folder: int, name: str, mode: int, strict: str | os.PathLike[str] | None = None
) -> Iterator[IO[bytes]]:
    """:func:`atomic_output`'s temp file and rename, in the open folder ``folder`` (closed
    here), of the file ``name`` there. ``strict`` (the path, for a message): only nothing or a
    regular file may be at ``name`` (a symbolic link, a FIFO, a device, a directory:
    :class:`OutputFileError`); the rename replaces the name itself, whatever was put there
    meanwhile, and never writes through it."""
    try:
        if strict is not None:
            try:
                st = os.stat(name, dir_fd=folder, follow_symlinks=False)
            except FileNotFoundError:
                pass
            else:
                if not stat.S_ISREG(st.st_mode):
                    raise OutputFileError(
                        f"{shown_path(strict)} is {_kind(st.st_mode)}: in a folder hdrd "
                        "writes a file of its own into, only a regular file is replaced"
                    )
        _remove_stale_temps(folder, name)
        fd, tmp = _temp_file(folder, name)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # ours: no cleaner may take it
            with os.fdopen(fd, "wb") as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
                os.fchmod(f.fileno(), mode)
                # still locked: a cleaner never sees it unlocked
                os.replace(tmp, name, src_dir_fd=folder, dst_dir_fd=folder)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp, dir_fd=folder)
            raise
        os.fsync(folder)
    finally:
        os.close(folder)


def _temp_file(folder: int, name: str) -> tuple[int, str]:
    """A new temp file ``.NAME.PID.RANDOM.tmp`` in the open folder, opened for writing,
    and its name."""
    for _ in range(100):
        tmp = f".{name}.{os.getpid()}.{os.urandom(6).hex()}.tmp"
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        try:
            return os.open(tmp, flags, 0o600, dir_fd=folder), tmp
        except FileExistsError:
            continue
        except OSError as e:  # named whole, as a path-based open would name it
            e.filename = os.path.join(_real_folder(folder), tmp)
            raise
    raise FileExistsError(f"no free temporary name for {name}")  # pragma: no cover


def _folder_inside(root: str | os.PathLike[str], path: str | os.PathLike[str]) -> int:
    """The open folder of ``path``, a path inside ``root``: ``root`` made if missing (with its
    parents: the user named it), then each folder on the way from it, made if missing and
    opened in turn, each checked to lie inside ``root`` (the folder really opened, as
    /proc/self/fd names it), so that no symbolic link among them leads out and nothing is made
    outside. OutputFileError if one does."""
    base = Path(root)
    base.mkdir(parents=True, exist_ok=True)
    parts = Path(path).relative_to(base).parts[:-1]
    flags = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC
    fd = os.open(base, flags)
    try:
        top = _real_folder(fd)
        for i, part in enumerate(parts):
            with contextlib.suppress(FileExistsError):
                os.mkdir(part, dir_fd=fd)
            nfd = os.open(part, flags, dir_fd=fd)
            os.close(fd)
            fd = nfd
            real = _real_folder(fd)
            if real != top and not real.startswith(top.rstrip("/") + "/"):
                way = shown_path(base.joinpath(*parts[: i + 1]))
                raise OutputFileError(
                    f"{way} leads out of {shown_path(base)} (a symbolic link): nothing is "
                    "written outside the folder named"
                )
        return fd
    except BaseException:
        os.close(fd)
        raise


def _real_folder(fd: int) -> str:
    """The real path of an open folder (/proc/self/fd's link: the folder opened, whatever
    names lead to it)."""
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:  # no /proc: the path it was opened by, resolved
        return os.path.realpath(f"/dev/fd/{fd}")


def missing_folder(path: str | os.PathLike[str]) -> str | None:
    """Why ``path`` cannot be made for want of its folder ("the folder F does not exist"), or
    None: a command's output is made in a folder that exists, never with its parents (a typo
    in ``--out /nonexistent/x.csv`` must not create ``/nonexistent``)."""
    folder = Path(path).parent
    return None if folder.is_dir() else f"the folder {shown_path(folder)} does not exist"


def write_problem(path: str | os.PathLike[str], folder: bool = False) -> str | None:
    """Why nothing can be written at ``path`` (a file; ``folder``: a folder to write files
    into), found by doing it: the missing folders made, a temporary file made and removed in
    the folder it goes in, then the folders made removed again (the writer makes them; a
    command that stops before it leaves nothing); None if that worked, or if ``path`` is a
    character device or a FIFO (written through, never replaced). For a command to say before
    its work what would otherwise fail after it (a folder that cannot be made, a read-only
    file system)."""
    target = Path(path)
    try:
        st = os.stat(target)
    except OSError:
        st = None
    if not folder and st is not None and (stat.S_ISCHR(st.st_mode) or stat.S_ISFIFO(st.st_mode)):
        return None
    where = target if folder else target.parent
    made = [p for p in (where, *where.parents) if not os.path.lexists(p)]
    doing = f"cannot make the folder {shown_path(where)}"
    try:
        where.mkdir(parents=True, exist_ok=True)
        doing = f"cannot write in {shown_path(where)}"
        fd = os.open(where, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            probe, name = _temp_file(fd, target.name if not folder else "probe")
            os.close(probe)
            os.unlink(name, dir_fd=fd)
        finally:
            os.close(fd)
    except OSError as e:
        return f"{doing}: {e.strerror or e}"
    finally:
        for folder_made in made:  # deepest first; only those still empty
            with contextlib.suppress(OSError):
                os.rmdir(folder_made)
    return None


def atomic_write_text(
    path: str | os.PathLike[str],
    text: str,
    mode: int = 0o644,
    inside: str | os.PathLike[str] | None = None,
) -> None:
    """:func:`atomic_output` of ``text`` (UTF-8), its folder made if need be (the bias file's
    state directory, a ``--json`` report's folder); ``inside``: as :func:`atomic_output`'s."""
    with atomic_output(path, mode, make_parents=True, inside=inside) as f:
        f.write(text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike[str], doc: Any) -> None:
    """:func:`atomic_write_text` of ``doc`` as indented JSON with a final newline (the
    ``--json``/``--report`` files of evaluate, tune and gap)."""
    import json

    atomic_write_text(path, json.dumps(doc, indent=2) + "\n")


def default_bias_path() -> Path:
    """$STATE_DIRECTORY/bias.yaml under systemd (StateDirectory=hdrd), else /var/lib/hdrd."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(state or "/var/lib/hdrd") / "bias.yaml"


# -- names from data as paths -----------------------------------------------------------------


class UnsafeNameError(HdrdError, ValueError):
    """A name from data that cannot become a path inside the output folder; the message names
    it (escaped, clipped) and says why."""


def printable(text: str) -> str:
    """``text`` with every character a terminal could act on (controls, ESC, bidirectional
    overrides: all that ``str.isprintable`` refuses) written as its Python escape, ``\\x1b``:
    a name from data shown in a message or a table cannot move the cursor or hide itself."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


MAX_SHOWN_PATH = 120
"""Longest path shown in a message, characters: a longer one keeps its end (the file's own
name), behind "..."."""


def shown_path(path: str | os.PathLike[str]) -> str:
    """A path for a message: :func:`printable`, and at most :data:`MAX_SHOWN_PATH`
    characters (its end kept)."""
    text = printable(os.fspath(path) if not isinstance(path, bytes) else os.fsdecode(path))
    if len(text) <= MAX_SHOWN_PATH:
        return text
    return "..." + text[len(text) - MAX_SHOWN_PATH + 3 :]


def _name_problem(name: str) -> str | None:
    if not name:
        return "is empty"
    size = len(name.encode("utf-8", "surrogatepass"))
    if size > MAX_NAME_BYTES:
        return f"is {size} bytes long, more than the {MAX_NAME_BYTES} a name may have"
    if not name.isprintable():
        return "holds a control or other non-printable character"
    if name.startswith("/"):
        return "is an absolute path"
    if any(part in ("", ".", "..") for part in name.split("/")):
        return "has an empty, '.' or '..' part"
    return None


def path_inside(root: str | os.PathLike[str], name: str, suffix: str = "") -> Path:
    """``root / (name + suffix)``, for a ``name`` that comes from data (a drive's name), made
    sure to lie inside ``root``: ``/`` in a name makes sub-folders of ``root`` (a drive found
    at ``DIR/phone/drive05.csv`` is ``phone/drive05``), but an empty name, one with a NUL or
    another control character, an absolute name, a ``.`` or ``..`` part, a name over
    :data:`MAX_NAME_BYTES` bytes, or one whose folders lead out of ``root`` through a symbolic
    link raise :class:`UnsafeNameError`. Nothing is created."""
    problem = _name_problem(name)
    base = Path(root)
    path = base / (name + suffix)
    if problem is None:
        # the folders that exist already (a symbolic link among them) must stay inside too
        real_root = base.resolve()
        real_parent = path.parent.resolve()
        if real_parent != real_root and real_root not in real_parent.parents:
            problem = f"leads out of {printable(str(base))} through a symbolic link"
    if problem is not None:
        raise UnsafeNameError(
            f"the name {clipped(repr(name), 80)} cannot name a file inside "
            f"{clipped(printable(str(base)), 120)}: it {problem}"
        )
    return path
