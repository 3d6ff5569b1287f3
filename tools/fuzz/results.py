"""What a fuzz run of tools/fuzz found, surface by surface (tools/fuzz/harness.py makes it):
the inputs, outcomes, defects (each with the first input that gave it), the costliest input
and memory; described as text and as a Markdown table."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["Defect", "SurfaceResult", "describe", "markdown"]


@dataclass
class Defect:
    kind: str  # "traceback", "broken", "hang", "death"
    signature: str
    first_input: int
    count: int = 1
    detail: str = ""
    input_bytes: int = 0


@dataclass
class SurfaceResult:
    surface: str
    seed: int
    inputs: int = 0
    seconds: float = 0.0
    outcomes: dict[str, int] = field(default_factory=dict)
    defects: list[Defect] = field(default_factory=list)
    hangs: int = 0
    deaths: int = 0
    tracebacks: int = 0
    slowest_s: float = 0.0
    slowest_input: int = -1
    largest_input_bytes: int = 0
    rss_start_mb: float = 0.0
    rss_end_mb: float = 0.0
    peak_rss_mb: float = 0.0
    peak_rise_mb: float = 0.0
    peak_rise_input: int = -1
    peak_rise_input_bytes: int = 0

    @property
    def ok(self) -> bool:
        return not self.defects

    def add_defect(self, kind: str, signature: str, i: int, detail: str, nbytes: int) -> None:
        for d in self.defects:
            if d.kind == kind and d.signature == signature:
                d.count += 1
                return
        if len(self.defects) < 50:
            self.defects.append(Defect(kind, signature, i, 1, detail[-3000:], nbytes))


def describe(r: SurfaceResult) -> str:
    rate = r.inputs / r.seconds if r.seconds else 0.0
    outcomes = ", ".join(f"{k} {v:,}" for k, v in sorted(r.outcomes.items(), key=lambda kv: -kv[1]))
    lines = [
        f"{r.surface}: {r.inputs:,} inputs in {r.seconds:.0f} s ({rate:,.0f}/s), seed {r.seed}",
        f"  outcomes: {outcomes}",
        f"  tracebacks {r.tracebacks}, hangs {r.hangs}, deaths {r.deaths}; costliest input "
        f"{r.slowest_s:.3f} s of CPU (#{r.slowest_input}); largest input "
        f"{r.largest_input_bytes:,} bytes",
        f"  RSS: {r.rss_start_mb:.0f} MB before the first input, peak {r.peak_rss_mb:.0f} MB "
        f"(largest rise +{r.peak_rise_mb:.1f} MB at #{r.peak_rise_input}, "
        f"{r.peak_rise_input_bytes:,} bytes), {r.rss_end_mb:.0f} MB at the end",
    ]
    for d in r.defects:
        lines.append(
            f"  DEFECT {d.kind} x{d.count}: {d.signature} (first: --show {r.surface}:{d.first_input}, "
            f"{d.input_bytes:,} bytes)"
        )
        if d.detail:
            lines.extend("    " + x for x in d.detail.rstrip().splitlines()[-6:])
    lines.append(f"  {'OK' if r.ok else 'FAILED'}")
    return "\n".join(lines)


def markdown(results: list[SurfaceResult]) -> str:
    head = (
        "| surface | inputs | seconds | tracebacks | hangs | deaths | costliest input, CPU s | "
        "peak RSS, MB (before the first input; largest rise by one input) | largest input, bytes "
        "| outcomes |\n"
        "|---|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = []
    for r in results:
        outcomes = ", ".join(
            f"{k} {v:,}" for k, v in sorted(r.outcomes.items(), key=lambda kv: -kv[1])
        )
        rows.append(
            f"| {r.surface} | {r.inputs:,} | {r.seconds:.0f} | {r.tracebacks} | {r.hangs} | "
            f"{r.deaths} | {r.slowest_s:.2f} | {r.peak_rss_mb:.0f} ({r.rss_start_mb:.0f}; "
            f"+{r.peak_rise_mb:.1f}) | "
            f"{r.largest_input_bytes:,} | {outcomes} |"
        )
    return head + "\n".join(rows) + "\n"
