"""The ``facecorr`` command line.

The top floor: every sub-command, one module per group (:mod:`.register`: register, batch, demo;
:mod:`.landmarks`; :mod:`.train`; :mod:`.evaluate`: the ``eval`` group; :mod:`.template`;
:mod:`.synth`), each with an ``add_commands(subparsers)``. Nothing in the package imports the CLI.
Heavy imports happen inside the handlers so ``facecorr --help`` is quick.
A user's mistake (:class:`facecorr.errors.FacecorrError`) prints one line and exits 2; anything
else is our fault: one line naming it, exit 1 (``FACECORR_DEBUG=1`` shows the traceback).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ..errors import FacecorrError

#: Modules contributing sub-commands, in help order.
COMMAND_MODULES = ("register", "landmarks", "train", "evaluate", "template", "synth")


def build_parser() -> argparse.ArgumentParser:
    from .._core import __version__

    parser = argparse.ArgumentParser(
        prog="facecorr",
        description="Fully automatic expression-invariant dense correspondence between 3D face scans.",
    )
    parser.add_argument("--version", action="version", version=f"facecorr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").add_commands(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        rc = args.func(args)
    except FacecorrError as e:
        print(f"facecorr: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("facecorr: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the last line of defence: one line, exit 1
        if os.environ.get("FACECORR_DEBUG"):
            raise
        msg = str(e).splitlines()[0] if str(e) else ""
        print(f"facecorr: internal error: {type(e).__name__}: {msg} "
              "(a bug: please report it; FACECORR_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
