#!/usr/bin/env bash
# Render and compare the paper-scale twins (issue 13), one after the other, resumably: rerunning
# renders only missing views and skips finished comparison stages. Hours on 2 cores; run it in the
# background:  nohup bash scripts/run-twins.sh > twins.log 2>&1 &
# OUT (default ./polarref-out/twins) holds the run folders (models, databases, caches: not for
# git); the small tables go to reports/paper-tables/ (commit those and its README).
# Our front end (features, matching, verification) uses every core by default (threads,
# polarref/sfm/frontend.py; OMP_NUM_THREADS caps it); a stage loaded from an earlier run's cache
# is named so in stages/*.json, with the time measured when the cache was made counted beside it.
# pycolmap runs on 2 threads (TwinRun.pycolmap_threads, issue 34; stored in run.json and the table).
# For three seeds from one pinned commit, resumable over sessions: scripts/twin-campaign.sh.
set -u
cd "$(dirname "$0")/.."
P=.venv/bin/polarref
OUT=${OUT:-polarref-out/twins}
TWINS=${TWINS:-"rosetta mappilot poets-park"}
mkdir -p "$OUT"
for twin in $TWINS; do
  case $twin in rosetta) kind=comet ;; *) kind=uav ;; esac
  dir=$(.venv/bin/python -c "from polarref.compare.run.scenes import synthetic_root as r; print(r('$kind', '$twin', 0))")
  echo "$(date -u +%FT%T) render $twin -> $dir"
  $P --no-progress render "$kind" --preset "$twin" --out "$dir" || { echo "render $twin failed"; continue; }
  echo "$(date -u +%FT%T) compare $twin"
  $P --no-progress compare "$twin" --out "$OUT/$twin" --tables reports/paper-tables \
    || echo "compare $twin failed (rc $?); rerun to resume"
done
echo "$(date -u +%FT%T) done"
