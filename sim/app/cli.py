"""The `jiggle` command line: the parser built from one module per subcommand (sim/app/commands/),
and `main`, which runs one.

Every user mistake (a bad file, a bad parameter) ends as one line on stderr naming the file, line or
parameter and what was expected, with exit code 2; tracebacks are for jiggle's own bugs.
"""
from __future__ import annotations

import argparse
import sys

from rig.base.errors import InputError
from sim.app.args import EXIT_USER_ERROR, Parser
from sim.app.commands import COMMANDS


def build_parser() -> argparse.ArgumentParser:
    top = Parser(prog="jiggle", description=(
        "Physics-backed muscle jiggle and secondary motion for animated characters. "
        "Start with 'jiggle demo'; bake your own clip with 'jiggle bake --clip FILE' and compare static "
        "with dynamic deformation with 'jiggle compare OUT_DIR'."),
        epilog="Run 'jiggle COMMAND --help' for a command's options. Exit codes: 0 done, 2 bad input, "
               "130 interrupted.")
    sub = top.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for command in COMMANDS:
        command.add_parser(sub)
    return top


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USER_ERROR
    import warnings

    from rig.base.errors import JiggleWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, JiggleWarning):
            print(f"jiggle: warning: {message}", file=sys.stderr)
        else:
            sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))
    try:
        with warnings.catch_warnings():  # restored afterwards, for callers that run main() in-process
            warnings.simplefilter("always", JiggleWarning)
            warnings.showwarning = show
            return int(args.func(args) or 0)
    except InputError as e:
        print(f"jiggle: error: {e}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("jiggle: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
