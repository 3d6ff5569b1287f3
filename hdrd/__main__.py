"""``python -m hdrd`` and the ``hdrd`` command (its entry point, :func:`main`).

First of all, before any import but the signals' own: ``hdrd run`` holds SIGHUP
(:func:`hdrd.daemon.signals.hold_hangup_for`), whose default action would end the daemon while it
starts (a reload sent early); the daemon takes a held one as a reload.
"""

import sys

from hdrd.daemon.signals import hold_hangup_for


def main() -> int:
    """The ``hdrd`` command."""
    hold_hangup_for(sys.argv[1:])
    # signals are held before the command line is imported
    from hdrd.cli import main as cli_main

    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
