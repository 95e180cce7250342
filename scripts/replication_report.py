"""Replicate C3, C4 and C5 on the pre-registered scenes and write replication.md/.json (issue 30).

    PYTHONPATH=. python scripts/replication_report.py --out reports/replication-small

Scenes come from ``polarref/compare/claims/preregistration.toml`` ``[replication]``; real sets are read
under ``--data`` (default: $POLARREF_DATA, else ../shared/data). Resumable: a scene folder with a
``metrics.json`` is reused, never rerun. An existing replication.json is replaced only with
--overwrite (the scene runs under it are reused either way).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from polarref.compare.run.replication import replicate
from polarref.compare.run.replication_render import render
from polarref.core import records
from polarref.core.atomic import atomic_write
from polarref.core.data import data_root

log = logging.getLogger("replication")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="report folder (one subfolder per scene)")
    ap.add_argument("--data", type=Path, default=None, help="data root of the real sets")
    ap.add_argument("--timeout", type=float, default=900.0, help="limit per scene run in seconds")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing replication.json/.md")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    if (args.out / "replication.json").exists() and not args.overwrite:
        print(f"{args.out}/replication.json exists: pass --overwrite to replace it (scene runs are reused)",
              file=sys.stderr)
        return 2
    data = args.data or data_root()
    rep = replicate(args.out, data, args.timeout, progress=lambda s: log.info("scene %s", s.folder))
    records.save(rep, args.out / "replication.json")
    atomic_write(args.out / "replication.md", render(rep))
    for r in rep.rows:
        log.info("%s: %s -> replicated %s", r.claim_id, ", ".join(r.verdicts), r.replicated)
    log.info("wrote %s in %.0f s", args.out / "replication.md", rep.wall_s)
    return 0 if all(s.status == "ok" for s in rep.scenes) else 1


if __name__ == "__main__":
    sys.exit(main())
