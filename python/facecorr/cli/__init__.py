"""The ``facecorr`` command line.

The top floor: every sub-command, one module per group (:mod:`.register`: register, batch, demo;
:mod:`.report`; :mod:`.landmarks`; :mod:`.train`; :mod:`.evaluate`: the ``eval`` group; :mod:`.model`: the
``model`` group (shape models); :mod:`.template`;
:mod:`.synth`), each with an ``add_commands(subparsers)``. Nothing in the package imports the CLI.
Heavy imports happen inside the handlers so ``facecorr --help`` is quick.
A user's mistake (:class:`facecorr.errors.FacecorrError`) prints one line and exits 2; anything
else is our fault: one line naming it, exit 1 (``FACECORR_DEBUG=1`` shows the traceback). A usage
mistake (argparse) is one line too, exit 2. Ctrl-C exits 130, SIGTERM 143 (both after cleaning up).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from ..errors import FacecorrError

#: Modules contributing sub-commands, in help order.
COMMAND_MODULES = ("register", "report", "landmarks", "train", "evaluate", "model", "template", "synth")


class Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors: ``facecorr: error: ...`` and exit 2."""

    def error(self, message):
        msg = " ".join(str(message).split())
        where = self.prog.split(None, 1)[1] if " " in self.prog else ""
        hint = f" (see '{self.prog} --help')"
        self.exit(2, f"facecorr: error: {where + ': ' if where else ''}{msg}{hint}\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so the same cleanups run (exit 143)."""


def _on_sigterm(signum, frame):
    raise Terminated()


def build_parser() -> argparse.ArgumentParser:
    from .._core import __version__

    parser = Parser(
        prog="facecorr",
        description="Fully automatic expression-invariant dense correspondence between 3D face scans.",
    )
    parser.add_argument("--version", action="version", version=f"facecorr {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").add_commands(sub)
    return parser


def main(argv=None) -> int:
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread (main() called from a thread): leave SIGTERM alone
        previous = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        rc = args.func(args)
    except FacecorrError as e:
        print(f"facecorr: error: {' '.join(str(e).splitlines())}", file=sys.stderr)
        return 2
    except Terminated:
        print("facecorr: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
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
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
