"""The ``polarref`` command line: one subcommand per pipeline stage.

Each module in :mod:`polarref.commands` defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; modules that fail to import are
reported by ``polarref doctor`` rather than shipped half-working. Logging handlers and
progress bars are set up here and nowhere else.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import io
import logging
import os
import signal
import sys
import threading
import traceback
import warnings

from polarref import __version__
from polarref.commands._registry import command_modules
from polarref.core import execution, progress
from polarref.core.heap import keep_heap
from polarref.core.errors import PolarrefError, UsageError, is_out_of_memory

log = logging.getLogger("polarref")


def _worker_count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of workers, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="polarref",
        description="Reference and verification suite for polar-coordinate photogrammetry.",
    )
    parser.add_argument("--version", action="version", version=f"polarref {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    parser.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_worker_count, metavar="N",
                       help="run per-view/per-image/per-pair tasks on N local Dask worker processes")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="run tasks on an existing Dask cluster (default: $POLARREF_SCHEDULER; "
                            "none: serial, in this process)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    modules, _ = command_modules()
    for module in modules:
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        # the inputs a message can name: positionals that are not a fixed choice ("bench ba")
        inputs = [a.dest for a in p._actions if not a.option_strings and a.choices is None]
        p.set_defaults(_run=module.run, _positionals=inputs)
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 0 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    # Python warnings (numpy RuntimeWarnings, ...) go through logging, as one line each.
    warnings.showwarning = _log_warning


def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    # a library's warning (numpy's "invalid value encountered", ...) names no problem of the
    # user's: shown with -v only; what the user must know, our own log.warning says in words
    logging.getLogger("py.warnings").debug("%s: %s (%s:%s)", category.__name__,
                                           _one_line(message), filename, lineno)


class _Interrupts:
    """Record SIGINT before raising KeyboardInterrupt, so an interrupt that a C extension
    (drjit, pycolmap) turns into another exception still ends as 'interrupted' (exit 130)."""

    def __init__(self) -> None:
        self.seen = False
        self._previous = None
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handler)

    def _handler(self, signum, frame) -> None:
        self.seen = True
        # What follows an interrupt (an extension's import failing half-way, a fallback warning)
        # is its consequence, not news: only the one 'interrupted' line is printed.
        logging.disable(logging.WARNING)
        raise KeyboardInterrupt

    def restore(self, exiting: bool) -> None:
        if self.seen:
            logging.disable(logging.NOTSET)
        if self._previous is None:
            return
        # A process about to exit ignores further SIGINTs, whether or not the command was
        # interrupted: its outputs are final, and a SIGINT during interpreter or drjit teardown
        # (drjit also re-raises one from its own handler) would kill it with -SIGINT and no line.
        signal.signal(signal.SIGINT, signal.SIG_IGN if exiting else self._previous)


def _primary_input(args: argparse.Namespace) -> str | None:
    """The first positional argument of the subcommand (what the user gave it to work on)."""
    for action in getattr(args, "_positionals", ()):
        value = getattr(args, action, None)
        if value not in (None, [], ""):
            return " ".join(map(str, value)) if isinstance(value, list) else str(value)
    return None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def describe(exc: BaseException, args: argparse.Namespace) -> str:
    """One line ``<input>: <what went wrong> (<what to do>)`` for any exception."""
    if isinstance(exc, PolarrefError):
        text = _one_line(exc)
        if exc.option:
            text += f" (use --{exc.option.replace('_', '-')})"
        return text
    if is_out_of_memory(exc):
        where = _primary_input(args)
        return (f"{where + ': ' if where else ''}out of memory"
                " (use a smaller input or preset, or free memory)")
    if isinstance(exc, OSError):
        name = exc.filename or _primary_input(args) or ""
        what = _one_line(exc.strerror or exc)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            todo = "free disk space or choose another output folder; nothing half-written was kept"
        elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            todo = "check permissions or choose another output path"
        elif exc.errno in (errno.ENOTDIR, errno.EISDIR, errno.EEXIST):
            todo = "a file stands where a folder is needed or the reverse; choose another path"
        elif exc.errno == errno.ENOENT:
            todo = "check the path"
        else:
            todo = "check the path and the disk"
        return f"{name + ': ' if name else ''}{what} ({todo})"
    where = _primary_input(args)
    return (f"{where + ': ' if where else ''}unexpected {type(exc).__name__}: {_one_line(exc)} "
            f"(rerun with -v for the traceback and report it)")


def _quiet_opencv() -> None:
    """OpenCV prints ``[ WARN ]`` lines straight to stderr (an unreadable image); our one line
    says it instead. The variable is read when cv2 loads; a loaded cv2 is told directly."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
    cv2 = sys.modules.get("cv2")
    with contextlib.suppress(AttributeError):
        if cv2 is not None:
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):
        pass


def _exit_now(code: int) -> None:
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand. Every failure ends here as one stderr line and an exit code:
    1 for errors, 2 for usage (argparse), 130 for Ctrl-C; tracebacks only with -v."""
    interrupts = _Interrupts()  # first: Ctrl-C while the commands are still importing counts too
    args = argparse.Namespace(command=None, verbose=0)
    _quiet_opencv()
    try:
        args = build_parser().parse_args(argv)  # exits 2 with usage on bad commands/options/values
        _setup_logging(args.verbose, args.quiet)
        keep_heap()  # the BA's per-iteration arrays stay mapped (core/heap.py)
        progress.enable(not args.no_progress and sys.stderr.isatty())
        spec = execution.configure(args.workers, args.scheduler)  # started on first use, closed at exit
        if args.command != "doctor":  # doctor reports an unreachable scheduler instead of failing
            execution.check_reachable(spec)  # before any output exists
        code = int(args._run(args) or 0)
        if interrupts.seen:  # an extension swallowed the KeyboardInterrupt; Ctrl-C still wins
            raise KeyboardInterrupt
        return code
    except SystemExit:
        raise
    except BrokenPipeError:
        # stdout closed early (``| head -1``): the reader has what it wanted and the outputs on
        # disk are complete (commands print their summary after writing), so exit quietly
        _silence_stdout()
        return 0
    except BaseException as exc:  # the one boundary: nothing escapes as a traceback
        name = f"polarref {args.command}" if args.command else "polarref"
        if args.verbose:
            traceback.print_exception(exc, file=sys.stderr)
        if isinstance(exc, KeyboardInterrupt) or interrupts.seen:
            print(f"{name}: interrupted; finished outputs were kept", file=sys.stderr)
            if argv is None:  # a real process: skip finalization, where an interrupted drjit/LLVM
                _exit_now(130)  # can abort (SIGABRT) after the line above; every output is closed
            return 130
        if isinstance(exc, UsageError):  # as argparse reports a bad option: "<prog>: error: ..."
            print(f"{name}: error: {_one_line(exc)}", file=sys.stderr)
            return 2
        print(f"{name}: {describe(exc, args)}", file=sys.stderr)
        return 1
    finally:
        interrupts.restore(exiting=argv is None)
