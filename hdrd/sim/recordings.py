"""The gyro errors ``hdrd gap`` fitted to a set of real drives, as the distribution simulated
routes draw their gyro from (:func:`errors_from`, :class:`FittedErrors`; docs/model-gap.md,
"From real drives to training routes"). (The profiles of one recording's sensor, which
bench/gap_real.py measures, are bench/recordings.py.)
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from hdrd.errors import clipped
from hdrd.io.files.access import InputFileError, printable, read_limited, shown_path
from hdrd.sim.gyro import GyroModel

__all__ = [
    "MAX_GAP_REPORT_BYTES",
    "NOT_THE_GYRO",
    "FittedErrors",
    "errors_from",
    "gyro_error_draws",
]

MAX_GAP_REPORT_BYTES = 64 << 20
"""Largest ``hdrd gap --report`` file read: 64 MiB (a fleet's reports run to 20-50 KB a drive:
1,300 to 3,000 drives)."""
MAX_GAP_REPORT_VALUES = 4_000_000
"""Most JSON values (objects, arrays, keys, numbers, strings) a report read may hold, counted
before any is built: a drive's report holds some 1,300 to 3,000 (18 bytes a value), but 64 MiB
of ``{},`` would be 22 million objects, 1.6 GB to build; 4 million of the smallest values take
some 300 MB."""

NOT_THE_GYRO = ("time_offset",)
"""Effects left out of a drive's draw when its truth was a heading (a GPS course): there a
``time_offset`` is the course's latency, not the gyro's."""


@dataclass(frozen=True)
class FittedErrors:
    """The gyro errors ``hdrd gap`` fitted to real drives: one model per drive (its report's
    ``final_params``), each drive equally likely. A simulated route draws the whole model of
    one drive (:meth:`draw`), so that the effects a real gyro showed together stay together
    (a random walk with the white noise it came with, a temperature slope with its bias).
    ``drives``: (name, model) in the report's order; ``source``: where they came from."""

    drives: tuple[tuple[str, GyroModel], ...]
    source: str = ""

    def draw(self, seed: int) -> tuple[str, GyroModel]:
        """The drive (name, model) route ``seed`` draws: uniform over the drives, from a
        stream of its own (the route, its temperature and its GPS keep theirs)."""
        rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x676170])  # "gap"
        return self.drives[int(rng.integers(len(self.drives)))]


def _report_model(rep: Any, where: str) -> tuple[str, GyroModel]:
    """One drive's (name, fitted model) from its report; ValueError naming what is wrong."""
    if not isinstance(rep, dict) or not isinstance(rep.get("final_params"), list):
        raise ValueError(f"{where}: not an hdrd gap report (no final_params list)")
    log: dict[str, Any] = rep["log"] if isinstance(rep.get("log"), dict) else {}
    name = str(log.get("name") or where)
    try:
        model = GyroModel.from_dict({"effects": rep["final_params"]})
    except (ValueError, TypeError) as exc:
        drive = f" ({clipped(printable(name), 80)})" if name != where else ""
        raise ValueError(f"{where}{drive}: {exc}") from None
    if str(log.get("truth", "")).startswith("heading_truth"):
        for effect in NOT_THE_GYRO:
            model = model.without(effect)
    return name, model


def errors_from(source: str | os.PathLike[str] | dict[str, Any]) -> FittedErrors:
    """The gyro errors of an ``hdrd gap --report`` file (one drive's report, or a fleet's
    ``{"drives": [...], "skipped": [...]}``), or of that JSON already read. Raises ValueError
    naming the file and what is wrong (one line), OSError if it cannot be read."""
    if isinstance(source, dict):
        doc: Any = source
        where = "the report"
    else:
        where = shown_path(source)
        try:
            doc = _report_json(read_limited(source, MAX_GAP_REPORT_BYTES), where)
        except InputFileError as e:
            raise ValueError(f"{where}: cannot be read: {e}") from None
    if not isinstance(doc, dict):
        raise ValueError(
            f"{where}: not an hdrd gap report (a JSON object: one drive's report, or "
            '{"drives": [report, ...]} of several)'
        )
    reports = doc.get("drives") if "drives" in doc else [doc]
    if not isinstance(reports, list) or not reports:
        raise ValueError(f"{where}: no drive's report in it")
    drives = tuple(
        _report_model(rep, f"{where}, drive {i + 1}" if len(reports) > 1 else where)
        for i, rep in enumerate(reports)
    )
    return FittedErrors(tuple((printable(n)[:100], m) for n, m in drives), where)


def _report_json(data: bytes, where: str) -> Any:
    """The JSON of a report's bytes, its values counted first (a comma, a colon or an opening
    bracket before each but the first, an empty pair once; those inside strings counted too) and
    refused beyond :data:`MAX_GAP_REPORT_VALUES` before any is built. ValueError naming
    ``where`` and what is wrong, in one line."""
    values = 1 + sum(data.count(c) for c in (b",", b":", b"[", b"{"))
    values -= data.count(b"{}") + data.count(b"[]")  # an empty one's comma counted it
    if values > MAX_GAP_REPORT_VALUES:
        raise ValueError(
            f"{where}: holds about {values:,} JSON values, more than the "
            f"{MAX_GAP_REPORT_VALUES:,} a report is read with (a drive's report: some 3,000)"
        )
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{where}: not JSON (not UTF-8 text)") from None
    except json.JSONDecodeError as e:
        raise ValueError(
            f"{where}: not JSON ({e.msg} at line {e.lineno}, column {e.colno})"
        ) from None
    except RecursionError:
        raise ValueError(f"{where}: not JSON this reads (nested too deep)") from None
    except ValueError as e:  # int() of more digits than Python converts
        digits = "more than 4300 digits" if "digits" in str(e) else type(e).__name__
        raise ValueError(f"{where}: not JSON (a number of {digits})") from None


def gyro_error_draws(
    source: str | os.PathLike[str] | dict[str, Any] | FittedErrors, seeds: Any
) -> list[GyroModel]:
    """The gyro model each route of ``seeds`` (an iterable of ints) draws from the errors of
    an ``hdrd gap`` report (:func:`errors_from`): for a drift reducer tuned on simulated routes
    whose gyros err as the real ones did."""
    errors = source if isinstance(source, FittedErrors) else errors_from(source)
    return [errors.draw(int(s))[1] for s in seeds]
