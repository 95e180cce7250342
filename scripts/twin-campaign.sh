#!/usr/bin/env bash
# The twin campaign (issue 34), a session at a time:
#   COMMIT=<sha> nohup bash scripts/twin-campaign.sh > campaign.log 2>&1 &
# Checks COMMIT out into a clean worktree under $WORK (the only code a cell runs), renders each
# twin with each seed (deterministic by seed), runs every (twin, seed, method) cell that has no
# result under reports/paper-tables/campaign/<COMMIT>/ yet, and writes one JSON per cell there.
# Commit those after every session (nothing else survives one): the next session runs only what
# is missing. Then `python -m polarref.compare.twins.campaign table COMMIT` writes table.json/.md
# (C4/C5 over the seeds; it refuses cells of any other commit).
# TWINS, SEEDS, METHODS, SIZE (twin | small | tiny) and PYCOLMAP_THREADS (default 2; 1 = the older
# tables' setting, a cell of its own) narrow or vary the run.
set -u
cd "$(dirname "$0")/.."
: "${COMMIT:?set COMMIT to the pinned commit}"
PY=${PY:-.venv/bin/python}
# the cells run in a worktree under $WORK, whose ../shared is not this checkout's: name the data
# (rosetta's shape model) by this checkout's default unless the caller set it
if [ -z "${POLARREF_DATA:-}" ] && [ -d ../shared/data ]; then
  POLARREF_DATA=$(cd ../shared/data && pwd)
  export POLARREF_DATA
fi
WORK=${WORK:-polarref-out/campaign}
TWINS=${TWINS:-"mappilot rosetta poets-park"}
SEEDS=${SEEDS:-"0 1 2"}
METHODS=${METHODS:-"ours-euclidean ours-polar pycolmap-incremental-sift pycolmap-global-sift"}
SIZE=${SIZE:-twin}
echo "$(date -u +%FT%T) campaign $COMMIT: twins $TWINS, seeds $SEEDS, size $SIZE"
# shellcheck disable=SC2086
nice -n "${NICE:-5}" "$PY" -m polarref.compare.twins.campaign run "$COMMIT" --twins $TWINS --seeds $SEEDS \
  --methods $METHODS --size "$SIZE" --pycolmap-threads "${PYCOLMAP_THREADS:-2}" --work "$WORK"
rc=$?
echo "$(date -u +%FT%T) campaign rc=$rc (rerun to resume; commit reports/paper-tables/campaign/)"
exit $rc
