"""The ``polarref`` command line: one subcommand per pipeline stage.

Each module in :mod:`polarref.commands` defines ``NAME``, ``HELP``,
``add_arguments(parser)`` and ``run(args) -> int``; modules that fail to import are
reported by ``polarref doctor`` rather than shipped half-working. Logging handlers and
progress bars are set up here and nowhere else.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from types import ModuleType

from polarref import __version__, execution, progress
from polarref.errors import PolarrefError

log = logging.getLogger("polarref")


def command_modules() -> tuple[list[ModuleType], dict[str, str]]:
    """Import every command module; return (loaded, {name: import error})."""
    import polarref.commands as pkg

    loaded: list[ModuleType] = []
    failed: dict[str, str] = {}
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        try:
            module = importlib.import_module(f"polarref.commands.{info.name}")
        except Exception as exc:  # a broken stage must not take the whole CLI down
            failed[info.name] = f"{type(exc).__name__}: {exc}"
            continue
        loaded.append(module)
    return loaded, failed


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
    where.add_argument("--workers", type=int, metavar="N",
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
        p.set_defaults(_run=module.run)
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 0 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)  # exits 2 with usage on unknown commands/options
    _setup_logging(args.verbose, args.quiet)
    progress.enable(not args.no_progress and sys.stderr.isatty())
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    execution.configure(args.workers, args.scheduler)  # started on first use, closed at exit
    try:
        return int(args._run(args) or 0)
    except PolarrefError as exc:
        print(f"polarref {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"polarref {args.command}: interrupted; finished outputs were kept", file=sys.stderr)
        return 130
