"""The ``spsr`` command installed by the wheel: the same program as the Rust binary."""

import signal
import sys

from . import _spsr


def main() -> None:
    """Run ``spsr`` with this process's arguments and exit with its exit code."""
    # Ctrl-C ends the program at once, as it does the native binary.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    sys.exit(_spsr.cli_main(["spsr", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
