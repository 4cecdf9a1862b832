"""The `chainsim` command line: the table of subcommands and the one place errors become exit codes.

Each subcommand is a module in `commands/` with NAME, HELP, add_parser(sub) and run(args). Only the
chosen command's module is imported, so `chainsim --help` and a light command never pay for numba,
GL or plotting imports. User errors (UserError) print as one line on stderr with exit code 2, never a
traceback; argparse usage errors also exit 2; Ctrl-C is one line and exit 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import re
import sys

from chainsim.game import __version__
from chainsim.game.common.logs import setup_logging
from chainsim.systems.engine.argtypes import NEGATIVE_NUMBER
from chainsim.systems.engine.errors import UserError, printable

# name -> one-line help, the same text as the module's HELP (a test holds them equal; kept here so
# `chainsim --help` imports no command); the module is chainsim.game.cli.commands.<name with - as _>
COMMANDS: dict[str, str] = {
    "bench": "run a benchmark (chainmail, render, ...)",
    "chainmail": "move one element of a mesh with Generalised ChainMail and save the result (.npz)",
    "docs": (
        "print reference documentation (components: every manifest key; limits: every input limit; "
        "models: every deformation model's parameters)"
    ),
    "new-pack": "create a new asset pack folder from a template",
    "packs": "list the asset packs found and where",
    "play": "open the simulator window on a pack",
    "protocol": (
        "run a study protocol with a participant at the window (or --scripted), save the attempts, "
        "print Table 6.1 over all participants"
    ),
    "rating": "a blinded rating of attempts by raters in the browser, and the raters' agreement",
    "records": "view, export, plot or delete trainee records (classes, trainees, attempts)",
    "replay": "replay a recorded session and compare its final digest",
    "run": "run a pack without a window and write OUT/summary.json",
    "serve": "run the records server: trainers' dashboard and JSON API over the records database",
    "snapshot": "render a pack's window layout off screen to a PNG",
    "study": "speed-accuracy study of ChainMail vs FEM and mass-spring; calibrate ChainMail presets",
    "study-report": "known-groups validity of a pack's metrics: novices against experts, pass marks, a report to file",
    "validate": "check a pack folder and report every problem",
    "warmup": (
        "compile every numba kernel a built-in pack can reach now (a minute or two, once per install) "
        "so nothing waits on it later"
    ),
}


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # `--to -1e3 0 0`: a negative number in e-notation is a value, not an option
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str):  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {printable(message)}\n")


def command_module(name: str):
    """The module that implements subcommand `name`."""
    return importlib.import_module(f"chainsim.game.cli.commands.{name.replace('-', '_')}")


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `chosen` (if it names a command) gets its full arguments."""
    parser = _Parser(prog="chainsim", description="Surgical-training simulator and ChainMail soft-tissue engine.")
    parser.add_argument("--version", action="version", version=f"chainsim {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="say more (-vv: debug)")
    parser.add_argument("-q", "--quiet", action="store_true", help="say only warnings and errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, help_ in COMMANDS.items():
        if name == chosen:
            mod = command_module(name)
            mod.add_parser(sub).set_defaults(_run=mod.run)
        else:
            sub.add_parser(name, help=help_)
    _escape_percent(parser)
    return parser


#: a `%` that starts no argparse placeholder (`%(default)s`) nor an escaped `%%`
_LONE_PERCENT = re.compile(r"%(?![(%])")


def _escape_percent(parser: argparse.ArgumentParser) -> None:
    """Double every lone `%` in help texts: argparse %-formats them, so "5 % of" in any command's or
    benchmark's help would end `--help` in a traceback."""
    for action in parser._actions:
        if isinstance(action.help, str):
            action.help = _LONE_PERCENT.sub("%%", action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if isinstance(choice.help, str):
                    choice.help = _LONE_PERCENT.sub("%%", choice.help)
            for sub in action.choices.values():
                _escape_percent(sub)


def _chosen(argv: list[str]) -> str | None:
    """The first argument that names a command (options before it are the top-level ones)."""
    return next((a for a in argv if a in COMMANDS), None)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser(_chosen(argv))  # imports the command's module: seconds for numba's
        args = parser.parse_args(argv)
    except SystemExit as e:  # usage errors (exit 2), --help and --version (exit 0) return a code here
        return int(e.code or 0)
    except KeyboardInterrupt:
        print("chainsim: interrupted", file=sys.stderr)
        return 130
    setup_logging(logging.WARNING if args.quiet else (logging.INFO, logging.DEBUG)[min(args.verbose, 1)])
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        code = args._run(args)
    except UserError as e:
        print(f"chainsim {args.command}: " + "\n".join(e.lines()), file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt as e:  # Interrupted says where the job stopped and what it kept
        print(f"chainsim {args.command}: {printable(str(e)) or 'interrupted'}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
