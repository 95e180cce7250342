#!/usr/bin/env bash
# One-stop set-up on a fresh Debian machine: system LLVM for Mitsuba's fast variant
# (optional: without it we render with scalar_rgb), a venv in .venv, the project + test extra.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! ls /usr/lib/*/libLLVM.so.19* >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null) \
      || echo "setup: could not install libllvm19; Mitsuba will fall back to scalar_rgb" >&2
  else
    echo "setup: not root or no apt-get; skipping libllvm19 (Mitsuba falls back to scalar_rgb)" >&2
  fi
fi
# Headless Chromium: the report's browser test and `polarref report --screenshot` (optional: the test
# skips with the reason without it).
if ! command -v chromium >/dev/null 2>&1; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
      || echo "setup: could not install chromium; the browser test will be skipped" >&2
  else
    echo "setup: not root or no apt-get; skipping chromium (the browser test will be skipped)" >&2
  fi
fi
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip 2>&1 | grep -v "is ignored" || true
.venv/bin/python -m pip install -q -e '.[test]' 2>&1 | grep -v "is ignored" || true
.venv/bin/python -c "import polarref, synth, derivations" || { echo "setup: install failed" >&2; exit 1; }
echo "setup: done ($(.venv/bin/polarref --version))"
