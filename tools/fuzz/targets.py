"""In-process fuzz targets of tools/fuzz: each input through the code the daemon runs.

A target is made once per worker (``harness.make_target(surface, seed, workdir)``) and keeps its state
across inputs, as a running daemon does; ``target.run(data) -> outcome`` takes one input
(tools/fuzz/inputs.py) and returns a short label of what happened ("accepted",
"rejected", ...). Anything it raises is a defect; so is a broken promise, raised as
:class:`Broken`:

- every published message: every number finite, heading in [0, 360), one line of JSON from
  :func:`hdrd.io.net.publish.format_json`, NMEA sentences that :func:`hdrd.io.net.publish.parse_nmea`
  reads back (the talker configured);
- a refused file: one printable line (:class:`hdrd.config.ConfigError` for a configuration,
  :class:`hdrd.io.files.biasfile.BiasFileError` for a bias file, a capture command's stderr);
- ``hdrd tail``: every line it would print is printable text;
- gpsd: the client stays in step with the peer (a marker line sent after each input is
  read) and the aiding publishes only finite values.

Surfaces and paths here: serial, the push parser (:class:`hdrd.io.wire.parser.Parser`) in
random chunks and the live pipeline a frame at a time (:meth:`hdrd.daemon.pipeline.Pipeline.feed`,
``resync``, ``stale_message``, ``finish``); clock, the same parser and the run loop's frame edge
(:meth:`hdrd.daemon.run.Daemon.take_frame`) at each frame's arrival time (:class:`ClockTarget`);
gpsd, a :class:`hdrd.io.net.gpsd.GpsdLink` (client and aiding) over a real loopback TCP
connection, its aid applied to the pipeline's steps; tail,
:meth:`hdrd.io.net.datagrams.TailFormatter.lines`. The files' surfaces (config, bias, capture)
are in tools/fuzz/filetargets.py.
"""

from __future__ import annotations

import json
import math
import random
import select
import socket
import time
from collections.abc import Iterable, Mapping, MutableMapping
from typing import Any

import numpy as np

from hdrd.core.calibrate import given_bias
from hdrd.core.methods import MethodSetup

from .contract import Broken, Target, check
from .inputs import stress_frames

__all__ = ["Broken", "Target"]


def check_messages(msgs: Iterable[Mapping[str, Any]], talker: str = "HN", ths: bool = True) -> int:
    """The published messages keep their promises (module doc); returns how many."""
    from hdrd.io.net.formats import format_json, nmea_sentences, parse_nmea

    n = 0
    for m in msgs:
        n += 1
        for k, v in m.items():
            if isinstance(v, float):
                check(math.isfinite(v), f"message {k} = {v!r}: {dict(m)}")
        h = m.get("heading")
        if h is not None:
            check(0.0 <= h < 360.0, f"heading {h!r} outside [0, 360)")
        line = format_json(m)
        check(line.endswith(b"\n") and line.count(b"\n") == 1, f"JSON line {line[:200]!r}")
        json.loads(line, parse_constant=_no_constant)
        for s in nmea_sentences(m, ths=ths, talker=talker):
            parse_nmea(s)
    return n


def _no_constant(name: str) -> Any:
    raise Broken(f"JSON line holds {name}")


# -- serial: push parser + live pipeline --------------------------------------------------------


def _pipeline_variants() -> list[Any]:
    from hdrd.core.calibrate import BiasRecord
    from hdrd.core.hdr import HdrParams
    from hdrd.daemon.stepper import PipelineConfig

    rec = BiasRecord(0.3, 0.05, 300, 30.0)
    return [
        PipelineConfig(setup=MethodSetup(bias=given_bias(0.1))),
        PipelineConfig(setup=MethodSetup(method="hdr+", bias=rec)),
        PipelineConfig(setup=MethodSetup(method="none", bias=given_bias(-2.9))),
        PipelineConfig(startup_s=1.0),  # a start-up calibration
        PipelineConfig(startup_s=0.5, setup=MethodSetup(method="hdr+")),
        PipelineConfig(
            setup=MethodSetup(
                hdr=HdrParams(T=0.01, c1=1000.0, c2=10.0, i_c=10.0), bias=given_bias(0.0)
            )
        ),
        PipelineConfig(setup=MethodSetup(hdr=HdrParams(T=60.0, tau=3600.0), bias=given_bias(0.0))),
    ]


class SerialTarget(Target):
    """The daemon's path for the gyro's bytes: parser fed in random chunks, the live
    pipeline a frame at a time; one parser and pipeline live across inputs (a daemon that
    never restarts; each input a reconnection, the parser flushed as on a loss), a new one
    every ``RESTART_EVERY`` inputs (another configuration)."""

    surface = "serial"
    RESTART_EVERY = 500

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(f"{seed}:serial-target")
        self.variants = _pipeline_variants()
        self.count = 0
        self.now = 1.7e9
        self._new()

    def _new(self) -> None:
        from hdrd.daemon.pipeline import Pipeline
        from hdrd.io.wire.parser import Parser

        k = (self.count // self.RESTART_EVERY) % len(self.variants)
        self.pipeline = Pipeline(self.variants[k])
        self.parsers = {"hdr-bin": Parser("hdr-bin"), "hdr-text": Parser("hdr-text")}

    def _shutdown(self) -> None:
        """What the daemon does at exit: the frames the parser held back, the last block."""
        msgs: list[dict[str, Any]] = []
        for parser in self.parsers.values():
            for f in parser.flush():
                msgs += self.pipeline.feed(f, parser.stats.bad_frames, self.now)
        msgs += self.pipeline.finish(0, self.now)
        check_messages(msgs)

    def run(self, data: bytes) -> str:
        if self.count and self.count % self.RESTART_EVERY == 0:
            self._shutdown()
            self._new()
        self.count += 1
        protocol = "hdr-bin" if data[:1] == b"B" else "hdr-text"
        parser = self.parsers[protocol]
        p = self.pipeline
        stream = memoryview(data)[1:]
        rng = self.rng
        frames = 0
        msgs: list[dict[str, Any]] = []
        # Each input is what a device sends after (re)connecting: the parser ends the last
        # one's input as the daemon does on a loss (its tracker forgets that device's rate).
        for f in parser.flush():
            frames += 1
            msgs += p.feed(f, parser.stats.bad_frames, self.now)
        pos = 0
        while pos < len(stream):
            n = rng.choice((1, 7, 64, 4096))
            for f in parser.feed(stream[pos : pos + n]):
                frames += 1
                msgs += p.feed(f, parser.stats.bad_frames, self.now)
            pos += n
        r = rng.random()
        self.now += 1.0
        if r < 0.05:
            msgs += p.resync(
                rng.choice((0.0, 0.5, 3.0, 1e6, 1e300)), parser.stats.bad_frames, self.now
            )
        elif r < 0.1:
            msgs.append(p.stale_message(self.now, rng.choice((3.0, 1e9)), parser.stats.bad_frames))
        check_messages(msgs)
        return "frames" if frames else "no frames"


# -- clock: the sequence and the device clock against the host's --------------------------------


class ClockTarget(Target):
    """A healthy stream broken by its sequence numbers and device clock
    (:func:`tools.fuzz.clockinputs.clock_input`), through what the daemon runs: the push parser
    (frame by frame, and in random chunks: the same as the vectorised decoder) and the run
    loop's frame edge (:meth:`hdrd.daemon.run.Daemon.take_frame`: the device clock against
    the host's, then the pipeline), each frame in hand at its arrival time. Promises: a frame
    labelled "drop" (a repeat; a frozen, slow or fast clock; a random frame) is never
    integrated, one labelled "integrate" always is; steps only go forward, and never by more
    than the host's clock allows (no gap_s of hours after a jump of the device clock); every
    message keeps the usual promises."""

    surface = "clock"
    SLACK_S = 12.0  # host-clock tolerance, jump re-anchoring and a step each side

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(f"{seed}:clock-target")

    def run(self, data: bytes) -> str:
        from hdrd.io.wire.capture import decode_capture, encode_array
        from hdrd.io.wire.codec import array_to_frames
        from hdrd.io.wire.parser import Parser

        from .clockinputs import CLOCK_ROW

        rows = np.frombuffer(data, CLOCK_ROW)
        wire = encode_array(rows["frame"])
        chunked = Parser()
        pos, got = 0, []
        while pos < len(wire):
            n = self.rng.choice((1, 16, 64, 4096))
            got += chunked.feed(wire[pos : pos + n])
            pos += n
        got += chunked.flush()
        arr, vst = decode_capture(wire)
        check(array_to_frames(arr) == got and vst == chunked.stats, "push parser != decoder")
        integrated = self._through_the_edge(Parser(), wire, rows)
        for i, label in enumerate(rows["label"].tolist()):
            check(label != 1 or i not in integrated, f"row {i} integrated, labelled drop")
            check(label != 0 or i in integrated, f"row {i} dropped, labelled integrate")
        return "all integrated" if len(integrated) == len(rows) else "some dropped"

    def _through_the_edge(self, parser: Any, wire: bytes, rows: Any) -> set[int]:
        """Each frame's bytes in turn into ``parser``, what it hands out into the run loop's
        frame edge at that frame's arrival; the rows integrated. Checks the steps."""
        from hdrd.config import Config
        from hdrd.core.calibrate import BiasRecord
        from hdrd.daemon.run import BiasChoice, Daemon

        d = Daemon(
            Config(),
            "fuzz",
            lambda: (Config(), "fuzz"),
            BiasChoice(BiasRecord(0.1, 0, 0, 0), "--bias"),
        )
        integrated: set[int] = set()
        last: tuple[int, float] | None = None  # step, host time of its last data
        last_in = 0.0  # host time of the last frame integrated
        arrival = rows["arrival"].tolist()
        for i in range(len(rows) + 1):
            frames = parser.feed(wire[16 * i : 16 * i + 16]) if i < len(rows) else parser.flush()
            now = arrival[min(i, len(rows) - 1)]
            for f in frames:
                mismatches = d.wallclock.mismatches
                msgs = d.take_frame(f, now, 0)
                check_messages(msgs)
                for m in msgs:  # a step's data ends with the frame integrated before this one
                    if last is not None:
                        self._check_step(m, last, last_in)
                    last = (m["step"], last_in)
                if d.wallclock.mismatches == mismatches:
                    integrated.add(f.rate)
                    last_in = now
        d.pipeline.finish()
        return integrated

    def _check_step(self, m: Mapping[str, Any], last: tuple[int, float], host: float) -> None:
        """Steps go forward, and by no more than the host's clock allows (T = 1 s)."""
        step, at = last
        allowed = host - at + self.SLACK_S
        check(m["step"] > step, f"step {m['step']} after {step}")
        check(
            m["step"] - step <= allowed and m.get("gap_s", 0.0) <= allowed,
            f"step {step} -> {m['step']} (gap_s {m.get('gap_s')}) in {host - at:.1f} s of "
            "host time",
        )


# -- gpsd: client + aiding over a real TCP connection ---------------------------------------------

MARKER = b'{"class":"VERSION","release":"fuzz-%d"}\n'


class GpsdTarget(Target):
    """A :class:`hdrd.io.net.gpsd.GpsdLink` connected to a loopback peer that this target plays:
    each input is sent (without blocking), then a newline and a marker line; the link is
    polled as the daemon's loop does until the marker is read. Between polls the pipeline
    gets a step's worth of frames, and each step goes through the link's aid."""

    surface = "gpsd"
    MAX_POLLS = 2000

    def __init__(self, seed: int) -> None:
        from hdrd.daemon.aiding import AidingConfig, GpsAiding
        from hdrd.daemon.gpslink import GpsdLink
        from hdrd.daemon.pipeline import Pipeline
        from hdrd.daemon.stepper import PipelineConfig
        from hdrd.io.net.gpsd import GpsdClient

        self.rng = random.Random(f"{seed}:gpsd-target")
        self.server = socket.create_server(("127.0.0.1", 0))
        port = self.server.getsockname()[1]
        self.clock = 1000.0
        client = GpsdClient("127.0.0.1", port, clock=lambda: self.clock)
        self.link = GpsdLink(client, GpsAiding(AidingConfig()), clock=lambda: self.clock)
        self.pipeline = Pipeline(
            PipelineConfig(setup=MethodSetup(method="hdr+", bias=given_bias(0.2))),
            self.link.aiding,
            lambda: self.clock,
        )
        self.peer: socket.socket | None = None
        self.count = 0
        self.t_us = 0
        self.frames = stress_frames(random.Random(seed), 10)
        self._connect()

    def _connect(self) -> None:
        for _ in range(100):
            self.link.poll(self.pipeline)
            r, _, _ = select.select([self.server], [], [], 0.05)
            if r:
                self.peer, _ = self.server.accept()
                self.peer.setblocking(False)
                break
        check(self.peer is not None, "the gpsd client did not connect")
        for _ in range(100):
            self.link.poll(self.pipeline)
            if self.link.client.connected:
                return
        raise Broken("the gpsd client did not finish connecting")

    def _step_frames(self) -> list[Any]:
        from hdrd.io.wire.codec import Frame

        out = []
        for k in range(10):
            self.t_us = (self.t_us + 100_000) % 2**32
            rate = 32768 + self.rng.choice((0, 0, 5, -5, 400))
            out.append(Frame(k, self.t_us, rate, 0, None))
        return out

    def run(self, data: bytes) -> str:
        from hdrd.io.net.gpsd import Version

        assert self.peer is not None
        self.count += 1
        marker = MARKER % self.count
        out = data + b"\n" + marker
        sent = 0
        before = self.link.client.stats.bad_lines
        fixes0 = self.link.client.stats.fixes
        for _ in range(self.MAX_POLLS):
            if sent < len(out):
                try:
                    sent += self.peer.send(out[sent : sent + 65536])
                except BlockingIOError:
                    pass
            self.clock += 0.1
            self.link.poll(self.pipeline, self.clock)
            check(self.link.client.connected, "the gpsd client dropped the connection")
            msgs: list[dict[str, Any]] = []
            for f in self._step_frames():
                msgs += self.pipeline.feed(f, 0, 1.7e9 + self.clock)
            self.link.log_mode(msgs, self.clock)
            check_messages(msgs)
            v = self.link.client.version
            if sent == len(out) and isinstance(v, Version) and v.release == f"fuzz-{self.count}":
                break
        else:
            raise Broken(f"the marker line after input {self.count} was never read")
        st = self.link.client.stats
        if st.bad_lines > before:
            return "bad lines"
        return "fix" if st.fixes > fixes0 else "other reports"

    def close(self) -> None:
        self.link.close()
        if self.peer is not None:
            self.peer.close()
        self.server.close()


# -- tail -----------------------------------------------------------------------------------------


class TailTarget(Target):
    surface = "tail"

    def __init__(self, seed: int) -> None:
        from hdrd.io.net.datagrams import TailFormatter

        self.formatters = [TailFormatter(raw=False), TailFormatter(raw=True)]
        self.count = 0

    def run(self, data: bytes) -> str:
        self.count += 1
        f = self.formatters[self.count % 2]
        out, notes, n = f.lines(data, sender="127.0.0.1:9")
        check(isinstance(n, int) and n >= 0, f"count {n!r}")
        for line in out + notes:
            check(isinstance(line, str) and line.isprintable(), f"tail prints {line[:200]!r}")
            line.encode("utf-8")  # what the terminal gets
        for note in notes:
            check(len(note) <= 400, f"a {len(note)}-character note")
        return (
            "printed"
            if out and not notes
            else "noted"
            if notes and not out
            else "both"
            if out
            else "nothing"
        )


# -- logging -------------------------------------------------------------------------------------


class _Events:
    """structlog processor that keeps the last events and drops them (no output)."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def __call__(self, logger: Any, name: str, event: MutableMapping[str, Any]) -> Any:
        import structlog

        self.events.append(dict(event))
        del self.events[:-20]
        raise structlog.DropEvent


def quiet_logging() -> _Events:
    import structlog

    events = _Events()
    structlog.configure(processors=[events], cache_logger_on_first_use=False)
    return events


def now() -> float:
    return time.perf_counter()
