"""The `jiggle` command line: the parser built from one module per subcommand (sim/app/commands/),
and `main`, which runs one (`python -m jiggle` runs it too).

Every user mistake (a bad file, a bad parameter) ends as one line on stderr naming the file, line or
parameter and what was expected, with exit code 2; tracebacks are for jiggle's own bugs. Warnings are
collected while the command runs and printed, in order, once it has succeeded: a command that fails
prints its error line alone. --quiet prints errors only; --verbose adds Warp's start-up and kernel-load
lines, the command's time and the warnings hidden by default (NumPy's floating-point ones).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
import warnings

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.sim.app.args import EXIT_USER_ERROR, Parser, output_options
from jiggle.sim.app.commands import COMMANDS

EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    top = Parser(prog="jiggle", description=(
        "Physics-backed muscle jiggle and secondary motion for animated characters. "
        "Start with 'jiggle demo'; bake your own clip with 'jiggle bake --clip FILE' and compare static "
        "with dynamic deformation with 'jiggle compare OUT_DIR'."),
        epilog="Run 'jiggle COMMAND --help' for a command's options ('python -m jiggle' is the same as "
               "'jiggle'). Output: progress bars and notices on stderr while a command runs, then its warnings, "
               "which are printed only when it succeeds (a failing command prints one error line); Warp's "
               "start-up and kernel-load lines and NumPy's overflow/invalid-value warnings are hidden unless "
               "--verbose; --quiet prints errors only. --quiet and --verbose go before or after COMMAND. "
               "Exit codes: 0 done, 1 some jobs of a batch failed, 2 bad input, 130 interrupted.")
    from jiggle._version import __version__
    top.add_argument("--version", action="version", version=f"jiggle {__version__}")
    output_options(top, top=True)
    sub = top.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for command in COMMANDS:
        command.add_parser(sub)
    for p in {id(p): p for p in sub.choices.values()}.values():
        output_options(p)
    return top


def hidden_by_default(w: warnings.WarningMessage) -> bool:
    """NumPy's floating-point RuntimeWarnings (overflow, invalid value, divide by zero, ...) and those
    raised inside NumPy: shown with --verbose only (the inputs that cause them are checked by jiggle)."""
    return issubclass(w.category, RuntimeWarning) and (
        " encountered in " in str(w.message) or f"{os.sep}numpy{os.sep}" in (w.filename or ""))


def show_warning(w: warnings.WarningMessage) -> None:
    if issubclass(w.category, JiggleWarning):
        print(f"jiggle: warning: {w.message}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))


@contextlib.contextmanager
def warp_output(verbose: bool, quiet: bool):
    """Warp's own output for the command: its start-up banner and "Module ... load on device ... took
    N ms" lines only with --verbose (then on stderr, not to mix with a command's stdout), its errors
    always; restored afterwards for callers that run main() in-process."""
    try:
        import warp
    except ImportError:       # pragma: no cover - warp is a dependency
        yield
        return
    cfg = warp.config
    old = {k: getattr(cfg, k) for k in ("quiet", "log_level") if hasattr(cfg, k)}
    cfg.quiet = not verbose                   # Warp before log_level (1.5 - 1.1x)
    if hasattr(cfg, "log_level"):
        cfg.log_level = warp.LOG_INFO if verbose else warp.LOG_ERROR if quiet else warp.LOG_WARNING
    old_logger = None
    if verbose and hasattr(warp, "set_logger") and hasattr(warp, "get_logger"):
        old_logger = warp.get_logger()

        class ToStderr:
            def debug(self, message):
                sys.stderr.write(message + "\n")
            info = debug

            def warning(self, message, category=None, stacklevel=1):
                old_logger.warning(message, category=category, stacklevel=stacklevel + 1)

            def error(self, message):
                old_logger.error(message)
        warp.set_logger(ToStderr())
    try:
        init_warp(warp, show=verbose)
        yield
    finally:
        if old_logger is not None:
            warp.set_logger(old_logger)
        for k, v in old.items():
            setattr(cfg, k, v)
        if "quiet" not in old:
            with contextlib.suppress(AttributeError):
                delattr(cfg, "quiet")


def init_warp(warp, show: bool) -> None:
    """wp.init() now, its native notices (e.g. "Warp CUDA warning: Could not find or load the NVIDIA CUDA
    driver" on a machine without a GPU, written straight to file descriptor 2) hidden unless `show`."""
    if show:
        warp.init()
        return
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:           # no file descriptor 2 (e.g. a GUI launcher): nothing to hide
        warp.init()
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
            warp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@contextlib.contextmanager
def silenced(on: bool):
    """--quiet: the command's stdout and stderr (progress bars, notices, files written) go nowhere;
    main prints the error line itself, after."""
    if not on:
        yield
        return
    with open(os.devnull, "w", encoding="utf-8") as null, contextlib.redirect_stdout(null), \
            contextlib.redirect_stderr(null):
        yield


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_USER_ERROR
    if args.quiet and args.verbose:
        parser.error("--quiet and --verbose do not go together")
    t0 = time.perf_counter()
    # restored afterwards, for callers that run main() in-process
    with warnings.catch_warnings(record=True) as caught, warp_output(args.verbose, args.quiet):
        warnings.simplefilter("always", JiggleWarning)
        try:
            with silenced(args.quiet):
                code = int(args.func(args) or 0)
        except InputError as e:
            print(f"jiggle: error: {e}", file=sys.stderr)
            return EXIT_USER_ERROR
        except (FileExistsError, NotADirectoryError, IsADirectoryError, PermissionError) as e:
            # a path the user gave that cannot be written or read as asked (an output "folder" that is a file)
            where = f"{e.filename}: " if e.filename else ""
            print(f"jiggle: error: {where}{e.strerror or e}; give another path", file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt as e:
            # run_bake's says how much was kept and how to resume
            print("jiggle: interrupted" + (f" {e}" if str(e) else ""), file=sys.stderr)
            return EXIT_INTERRUPTED
    if code == 0 and not args.quiet:
        for w in caught:
            if args.verbose or not hidden_by_default(w):
                show_warning(w)
    if args.verbose:
        print(f"jiggle: {args.command} took {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
