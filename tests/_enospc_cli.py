"""``python tests/_enospc_cli.py ARGS...``: the polarref CLI in a fresh process whose disk is full.

Every file that :mod:`polarref.core.atomic` opens for writing fails on its first write with
ENOSPC, as a full disk does (the open itself succeeds). Only that module's ``open`` is replaced,
so imports, logging and the terminal work as in a real run.
"""

from __future__ import annotations

import builtins
import errno
import os
import sys

import polarref.core.atomic as atomic


class _FullDisk:
    def __init__(self, fh) -> None:
        self._fh = fh

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self._fh.close()


def _open(file, mode="r", *args, **kwargs):
    fh = builtins.open(file, mode, *args, **kwargs)
    return _FullDisk(fh) if any(c in mode for c in "wax") else fh


atomic.open = _open

if __name__ == "__main__":
    from polarref.cli import main

    sys.exit(main(sys.argv[1:]))
