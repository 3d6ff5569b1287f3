"""One module per ``hdrd`` command: its ``main(args)`` (the parsing is :mod:`hdrd.cli`'s).

run, calibrate, tail, web, record, replay and convert, fakegyro, simulate, import, evaluate, tune,
gap; :mod:`~hdrd.cliconfig` turns the shared options into a configuration.
"""
