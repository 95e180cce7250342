"""Join the parts of one aerotriangulation run split by form (aerotri_table.py --forms ...) into
OUT/aerotriangulation.json and .md (polarref.georef.table.merge_tables).

Usage: python scripts/aerotri_merge.py OUT PART_DIR [PART_DIR ...] [--overwrite]
"""

import argparse
import json
import sys
from pathlib import Path

from polarref.georef.table import AerotriTable, merge_tables


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("parts", type=Path, nargs="+")
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args()
    if (a.out / "aerotriangulation.json").exists() and not a.overwrite:
        print(f"aerotri_merge: {a.out / 'aerotriangulation.json'} exists (pass --overwrite)", file=sys.stderr)
        return 1
    try:
        parts = [AerotriTable.from_json(json.loads((p / "aerotriangulation.json").read_text())) for p in a.parts]
        table = merge_tables(parts)
    except (OSError, ValueError, KeyError) as exc:
        print(f"aerotri_merge: {exc}", file=sys.stderr)
        return 1
    table.write(a.out)
    print(table.markdown())
    return 0


if __name__ == "__main__":
    sys.exit(main())
