"""The ``masknet`` command: a thin layer over the Python API.

One module per command, each with ``add_parser(subparsers)`` and ``run(args)``; the
options several commands share are in :mod:`masknet.cli._common`. Heavy imports
happen inside ``run``, so ``masknet --help`` stays fast.

Every failure caused by input (missing file, bad format, NaN rows, wrong shape)
is printed as one line, ``masknet: error: <file>: <problem>``, with exit code 2. Every
:class:`~masknet.errors.MaskNetWarning` the API issues is printed as one line,
``masknet: warning: <message>``, once.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

from masknet.cli import (
    benchmark,
    demo,
    denoise,
    evaluate,
    make_sample,
    mask,
    register,
    register_many,
    show,
    track,
    train,
)
from masknet.errors import MaskNetError, MaskNetWarning

__all__ = ["COMMANDS", "main", "build_parser", "run_script"]

# Command name -> its module, in the order ``masknet --help`` lists them: what a newcomer
# runs first (register, mask) first, training and the sample's rebuild last.
COMMANDS = {
    "register": register,
    "mask": mask,
    "register-many": register_many,
    "track": track,
    "denoise": denoise,
    "show": show,
    "demo": demo,
    "evaluate": evaluate,
    "benchmark": benchmark,
    "train": train,
    "make-sample": make_sample,
}


class _Parser(argparse.ArgumentParser):
    """argparse's parser, with a refusal on one line (no usage block above it) and no
    abbreviated long options (``--max-iteration`` is not taken for ``--max-iterations``)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # argparse calls it, and it exits with code 2
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _CommandsFormatter(argparse.HelpFormatter):
    """argparse's help, with room for the longest command name, so that each command of
    ``masknet --help`` is listed on one line (argparse leaves the listed commands out when
    it sizes the name column)."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog)
        self._action_max_length = 4 + max(map(len, COMMANDS))  # indented by 4


def build_parser() -> argparse.ArgumentParser:
    """The ``masknet`` parser: one subparser per command of :data:`COMMANDS`."""
    from masknet import __version__

    parser = _Parser(
        prog="masknet",
        description="MaskNet: predict which template points a partial source cloud also "
        "sees, and register the two. Start with: masknet register TEMPLATE SOURCE -o OUT.ply "
        "(masknet COMMAND --help for each command's options).",
        formatter_class=_CommandsFormatter,
    )
    parser.add_argument("--version", action="version", version=f"masknet {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, title="commands", metavar="COMMAND")
    for module in COMMANDS.values():
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``masknet`` with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    args = build_parser().parse_args(argv)
    shown, problems = warnings.showwarning, set()

    def one_line(message, category, filename, lineno, file=None, line=None):
        if not issubclass(category, MaskNetWarning):
            shown(message, category, filename, lineno, file, line)
            return
        # Every command reads its files first, and the checks name the file then
        # ("scan.ply: only 6 points"). The API checks the same arrays again under their
        # roles ("source: only 6 points"): that repeat says nothing new.
        text = str(message)
        if text.split(": ", 1)[0].split(" ")[0] in ("template", "source") or text in problems:
            return
        problems.add(text)
        print(f"masknet: warning: {text}", file=sys.stderr)

    def run() -> object:
        with warnings.catch_warnings():
            warnings.simplefilter("default", MaskNetWarning)  # each message once
            warnings.showwarning = one_line
            return COMMANDS[args.command].run(args)

    # The guard holds the warnings' setup and teardown too: Ctrl-C landing there, once the
    # outputs are written, still gets its one line and exit 130.
    return _guarded(run, "masknet")


def entry() -> None:
    """The ``masknet`` command (and ``python -m masknet.cli``): :func:`main`, then the exit
    with its code. Once ``main`` has returned, the outputs are written and the code is
    decided: a Ctrl-C landing in the interpreter's exit would only turn a finished run into
    exit 130 without a word, so it is ignored from there."""
    code = main()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise SystemExit(code)


def run_script(main: Callable[[], object]) -> None:
    """Run a helper script's ``main()`` as ``masknet`` runs a command: a MaskNetError (a
    missing file, a bad option) ends it with one line ``<script>: error: <problem>`` and
    exit code 2, not a traceback; Ctrl-C with exit code 130."""
    raise SystemExit(_guarded(main, Path(sys.argv[0]).name))


def _guarded(call: Callable[[], object], prog: str) -> int:
    """Run ``call``; the exit code, with one line on stderr for a refusal or Ctrl-C."""
    try:
        code = call()
    except MaskNetError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        print(f"{prog}: interrupted{f'; {exc}' if str(exc) else ''}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. `masknet ... | head`: stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return code if isinstance(code, int) else 0
