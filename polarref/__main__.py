"""Entry point of ``python -m polarref`` and of the ``polarref`` script.

Ctrl-C counts from the first line of ours that runs. :func:`polarref.cli.main` installs its own
handler, but only after ``polarref.cli``'s imports (numpy, ctypes, the command registry), which
take a tenth of a second on a quiet machine and over half a second on a loaded one; a SIGINT in
that window ended in an import traceback and exit -2 instead of the one 'interrupted' line and
exit 130. Only the standard library is imported before the guard is up; a SIGINT inside the
interpreter's own start-up (site, .pth files: a few hundredths of a second) precedes any code
of ours and ends as Python ends it.
"""

import os
import signal
import sys

INTERRUPTED = "polarref: interrupted; finished outputs were kept"


def run() -> None:
    seen = []

    def record(signum, frame):
        seen.append(signum)  # an extension's import may turn the KeyboardInterrupt into ImportError
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, record)
    try:
        from polarref.cli import main  # here, not at the top: the guard must precede these imports

        code = main()
    except BaseException:
        if not seen:
            raise
        sys.stderr.write(INTERRUPTED + "\n")
        sys.stderr.flush()
        os._exit(130)  # a half-imported extension is not finalised
    sys.exit(code)


if __name__ == "__main__":
    run()
