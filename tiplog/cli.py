"""`tiplog`: the one entry point. Each subcommand's arguments and work live in the package that
owns it, imported only when that subcommand is chosen (`tiplog --help` lists them all from
`COMMANDS` alone), so the top-level help stays fast and a missing optional dependency only
affects its own subcommand."""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from collections.abc import Sequence
from functools import partial
from typing import NoReturn

from tiplog import __version__
from tiplog.config import ConfigError
from tiplog.service import setup_logging
from tiplog.userio import UserError, forget_inputs

# command -> (module providing register(parser), one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("tiplog.up", "run the whole system (simulated bench by default)"),
    "sim": ("services.bench.cli", "generate simulated sessions and fidelity reports"),
    "replay": ("services.recorder.replay_cli", "publish a recording back onto the bus"),
    "fusion": ("services.fusion.cli", "run the filter offline on a recording, with sensor subsets"),
    "evaluate": ("study.cli", "paper tables and plots against the ground truth"),
    "calibrate": ("tiplog.calibration.cli", "fit calibration constants from a fit-only session"),
    "vision": ("services.vision.cli", "vision tools: train the segmentation network, run on a file"),
    "record": ("services.recorder.cli", "record the bus to MCAP; control a running recorder; recover a file"),
    "info": ("services.recorder.info_cli", "duration, topics, rates, counts, gaps and metadata of a recording"),
    "metrics": ("services.fusion.skill.cli", "skill-assessment metrics of a recording, with their uncertainty"),
    "export": ("tiplog.export.cli", "a recording's estimate as a LeRobot dataset, a Slicer sequence or CSV"),
}


class Parser(argparse.ArgumentParser):
    """A mistake on the command line (an unknown option, a value of the wrong kind) is one line
    naming it and where the usage is, exit status 2, like every other user error; `--help`
    still prints the whole usage. Subcommands' parsers are of this class too (argparse makes
    sub-parsers of their parent's class)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


class _Unparsable(Exception):
    pass


class _PreParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise _Unparsable(message)


def chosen_command(argv: Sequence[str] | None) -> str | None:
    """The subcommand a command line names (None: none, or not one of `COMMANDS`), read with the
    top-level options as the full parser reads them (abbreviations included)."""
    pre = _PreParser(prog="tiplog", add_help=False)
    pre.add_argument("--version", action="store_true")
    pre.add_argument("--log-level")
    pre.add_argument("command", nargs="?")
    pre.add_argument("rest", nargs=argparse.REMAINDER)
    try:
        ns, _ = pre.parse_known_args(sys.argv[1:] if argv is None else list(argv))
    except _Unparsable:
        return None
    return ns.command if ns.command in COMMANDS else None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole parser, with `command`'s own arguments (its module imported); every other
    subcommand is there by name and help only. `command="all"` registers every one."""
    parser = Parser(
        prog="tiplog",
        description="Record how a hand-held laparoscopic instrument moves: IMU, ToF and camera fused under the trocar's remote centre of motion.",
    )
    parser.add_argument("--version", action="version", version=f"tiplog {__version__}")
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if command in (name, "all"):
            try:
                mod = importlib.import_module(module)
            except ModuleNotFoundError as e:
                if e.name != module.partition(".")[0]:
                    raise
                # the study package ships with the source tree, not the OR image
                p.add_argument("args", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
                p.set_defaults(func=partial(_not_installed, e.name))
                continue
            mod.register(p)
    return parser


def _not_installed(package: str, _args: argparse.Namespace) -> int:
    raise UserError(f"the {package} package is not installed here (it comes with the source tree, not the OR image)")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(chosen_command(argv))
    args = parser.parse_args(argv)
    setup_logging(args.log_level)
    func = getattr(args, "func", None)
    if func is None:
        parser.parse_args([args.command, "--help"])
        return 2
    forget_inputs()  # the inputs an output may not replace are this command's alone
    try:
        return int(func(args) or 0)
    except ConfigError as e:
        print(str(e), file=sys.stderr)
        return 2
    except UserError as e:
        print(f"tiplog {args.command}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `tiplog info X | head`: the reader left, nothing to report
        return 0
    except Exception:
        traceback.print_exc()
        print(
            f"tiplog {args.command}: internal error: a bug in tiplog {__version__}, not in your input; please "
            "report it on the project's issue tracker with the command line and the traceback above",
            file=sys.stderr,
        )
        return 70  # EX_SOFTWARE


if __name__ == "__main__":
    sys.exit(main())
