"""The fuzzer of hdrd's input surfaces, a test-side tool (run from the repository root).

    python -m tools.fuzz --help          # the harness: tools/fuzz/harness.py
    python -m tools.fuzz.stream --help   # the long-stream check of the frame parsers alone

Modules: ``harness`` (the watched worker processes, the command line), ``surfaces``,
``inputs``, ``clockinputs`` and ``mutate`` (input *i* of a surface from (seed, surface, i)
alone), ``contract`` (what every target promises), ``targets`` and ``filetargets`` (each
surface's input through the code the daemon runs, by its public interfaces: the streams, the
files), ``driveinputs`` and ``drivelog`` (drive-log files for ``hdrd evaluate``/``tune``/``gap``:
the inputs, the target), ``process``, ``procbase`` and ``procinput`` (hdrd as processes),
``results`` (what a run found, as text and a table), ``stream`` (10^7 random bytes per
protocol through both parsers against a reference scan).
Results: bench/RESULTS.md, "Fuzz".
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: one core's worth
