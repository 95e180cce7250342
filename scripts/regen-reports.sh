#!/usr/bin/env bash
# Regenerate the committed example reports under reports/, their screenshots and the index page.
# The only command that writes into reports/ (polarref compare writes ./polarref-out/ by default).
# About 15 minutes on 2 cores (the comparisons plus the replication, below); needs ../shared/data for the fountain report and
# Chromium (scripts/setup.sh installs it as root) for the screenshots.
set -euo pipefail
cd "$(dirname "$0")/.."
P=.venv/bin/polarref
DATA=${POLARREF_DATA:-../shared/data}
$P --no-progress -q compare comet --preset small --out reports/comet-small --overwrite
$P --no-progress -q compare --out reports/comet-default --overwrite
$P --no-progress -q compare "$DATA/strecha_fountain-P11" --preset small \
  --out reports/strecha_fountain-P11-small --overwrite
# Replication of C3-C5 on the pre-registered scenes (comet seeds 1-3 + the fountain set, small
# preset, 3 methods, no claim experiments): about 11 minutes on 2 cores under load ~7-10 (677 s
# measured), a few minutes on quiet ones; the scene runs are reused unless their folder is removed.
rm -rf reports/replication-small
PYTHONPATH=. .venv/bin/python scripts/replication_report.py --out reports/replication-small --data "$DATA"
# Work products (databases, logs, models) stay out of git: reports/*/runs/ is ignored.
$P --no-progress report --screenshot reports/comet-small reports/comet-default reports/strecha_fountain-P11-small
$P --no-progress report --index reports
# The README's findings and run times are generated from the metrics.json just written (tests compare them).
.venv/bin/python -m polarref.compare.report.readme_findings reports README.md
.venv/bin/python -m polarref.compare.report.readme_runtime reports README.md
.venv/bin/python -m polarref.georef.readme reports README.md
.venv/bin/python -m polarref.compare.twins.readme_scale reports/paper-tables README.md
.venv/bin/python -m polarref.compare.twins.readme_campaign reports/paper-tables/campaign README.md
