#!/usr/bin/env bash
# Build the documentation site and check it (what CI runs for the docs):
#   1. ./.venv by scripts/setup.sh (torch==2.13.0 named in its pip command: the API pages'
#      autodoc imports training), then the [docs] extra into it (Sphinx, furo, MyST, Selenium);
#   2. Debian's chromium and chromium-driver, with apt-get, only when either is missing;
#   3. docs/gen_env_pages.py --check: the env pages (docs/envs/) are what the package says now;
#   4. the HTML site with warnings as errors, into docs/_build/html (a clean build: Sphinx
#      repeats no warning of a page it does not read again);
#   5. the linkcheck builder (external URLs skipped: CI may have no network);
#   6. scripts/check_docs_pages.py: internal links and anchors of the built pages, no machine
#      path in them, and three pages in headless Chromium (no console error, every image loaded).
# Open docs/_build/html/index.html afterwards. SKIP_SETUP=1 skips step 1 (an existing .venv).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS

if [ "${SKIP_SETUP:-0}" != 1 ]; then
  bash scripts/setup.sh
  .venv/bin/python -m pip install -q -e '.[docs]'
fi

if ! command -v chromium >/dev/null 2>&1 || ! command -v chromedriver >/dev/null 2>&1; then
  SUDO=""
  if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
  echo "== installing chromium and chromium-driver (apt-get)"
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    chromium chromium-driver >/dev/null
fi

echo "== env pages"
.venv/bin/python docs/gen_env_pages.py --check

echo "== html (warnings are errors)"
rm -rf docs/_build
.venv/bin/sphinx-build -W --keep-going -q -b html -d docs/_build/doctrees docs docs/_build/html

echo "== linkcheck"
.venv/bin/sphinx-build -W --keep-going -q -b linkcheck -d docs/_build/doctrees docs \
  docs/_build/linkcheck

echo "== pages (links, anchors, images, console errors in Chromium)"
.venv/bin/python scripts/check_docs_pages.py --html docs/_build/html

echo "docs: built and checked in $((SECONDS - start)) s: docs/_build/html/index.html"
