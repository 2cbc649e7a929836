"""Check the built documentation site: its internal links and anchors, then pages in Chromium.

    python scripts/check_docs_pages.py [--html docs/_build/html] [--page PATH ...] [--no-browser]

1. **Links** (no browser): every ``href``/``src`` of every built page that points inside the
   site must name a file that exists, and its ``#fragment`` an ``id`` of that page. (Sphinx's
   ``linkcheck`` builder checks external URLs only; it marks internal ones "unchecked".) No
   page may contain this machine's checkout or home folder (an absolute path autodoc or a page
   would publish).
2. **Browser**: the site is served on ``127.0.0.1`` (``http.server`` in a thread) and a few
   pages (the landing page, an env page, the leaderboard; ``--page`` names others) are opened
   in headless Chromium through Selenium and chromedriver. A page fails when its console has
   an error (a JavaScript exception, a resource that did not load) or when one of its
   ``<img>`` did not load (``naturalWidth == 0``).

Chromium and chromedriver are Debian's (``apt-get install chromium chromium-driver``;
``scripts/docs.sh`` installs them when missing); ``CHROMIUM`` and ``CHROMEDRIVER`` name other
binaries. Exit status 1 on any failure, each named on standard error.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import os
import shutil
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from html.parser import HTMLParser
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import unquote, urlsplit

if TYPE_CHECKING:
    from selenium.webdriver.chromium.webdriver import ChromiumDriver

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_HTML = ROOT / "docs" / "_build" / "html"
#: The pages the browser opens by default: the landing page, one env page, the leaderboard.
DEFAULT_PAGES = ("index.html", "envs/study_c.html", "leaderboard.html")
#: Seconds a page has to finish loading its images.
LOAD_TIMEOUT = 20.0


class _Page(HTMLParser):
    """The ids of one HTML page and the internal URLs it refers to."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.ids: set[str] = set()
        self.refs: list[tuple[int, str]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is None:
                continue
            if name in ("id", "name") and (name == "id" or tag == "a"):
                self.ids.add(value)
            if name in ("href", "src") and tag in ("a", "img", "link", "script"):
                self.refs.append((self.getpos()[0], value))


def _internal(url: str) -> bool:
    parts = urlsplit(url)
    return not parts.scheme and not parts.netloc and not url.startswith("//")


@functools.cache
def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8", errors="replace"))
    return page


def _machine_paths() -> list[str]:
    """This machine's folders that no published page may name."""
    folders = {str(ROOT), str(ROOT.resolve()), str(Path.home())}
    return sorted(f + "/" for f in folders if len(f) > 1)


def link_errors(html: Path) -> Iterator[str]:
    """``file:line: message`` for every broken internal link or anchor of the site, and for
    every line that names this machine's checkout or home folder."""
    machine = _machine_paths()
    for path in sorted(html.rglob("*.html")):
        text = path.read_text(encoding="utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), start=1):
            for folder in machine:
                if folder in line:
                    yield f"{path.relative_to(html)}:{number}: names this machine's {folder}"
        page = _parse(path)
        for line, url in page.refs:
            if not _internal(url):
                continue
            parts = urlsplit(url)
            target = (path.parent / unquote(parts.path)).resolve() if parts.path else path
            where = f"{path.relative_to(html)}:{line}"
            if target.is_dir():
                target = target / "index.html"
            if not target.is_relative_to(html.resolve()) and not target.is_file():
                yield f"{where}: {url!r} points outside the site"
            elif not target.is_file():
                yield f"{where}: {url!r}: no such file"
            elif parts.fragment and target.suffix == ".html":
                if unquote(parts.fragment) not in _parse(target).ids:
                    yield f"{where}: {url!r}: no id {parts.fragment!r} in {target.name}"


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:
        pass


def _serve(html: Path) -> http.server.ThreadingHTTPServer:
    handler = functools.partial(_QuietHandler, directory=str(html))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


def _binary(env: str, *names: str) -> str:
    if os.environ.get(env):
        return os.environ[env]
    for name in names:
        found = shutil.which(name)
        if found:
            return found
    raise SystemExit(
        f"check_docs_pages: no {names[0]} found (apt-get install chromium chromium-driver, or "
        f"set {env})"
    )


def _driver() -> ChromiumDriver:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = _binary("CHROMIUM", "chromium", "chromium-browser", "google-chrome")
    for flag in (
        "--headless=new",
        "--no-sandbox",  # CI runs as root, where Chromium's sandbox does not start
        "--disable-dev-shm-usage",
        "--disable-gpu",
        "--window-size=1280,1000",
    ):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # An explicit chromedriver: Selenium Manager would otherwise try to download one.
    service = Service(executable_path=_binary("CHROMEDRIVER", "chromedriver"))
    return webdriver.Chrome(options=options, service=service)


_BROKEN_IMAGES = """
return Array.from(document.images)
    .filter(img => img.complete && img.naturalWidth === 0)
    .map(img => img.getAttribute('src'));
"""
_PENDING_IMAGES = "return Array.from(document.images).filter(img => !img.complete).length;"


def browser_errors(html: Path, pages: Sequence[str]) -> Iterator[str]:
    """``page: message`` for each console error and each image that did not load."""
    server = _serve(html)
    driver = _driver()
    try:
        base = f"http://127.0.0.1:{server.server_address[1]}/"
        for page in pages:
            if not (html / page).is_file():
                yield f"{page}: not in the built site"
                continue
            driver.get(base + page)
            # Load every image (lazy ones too), then wait for them.
            driver.execute_script(
                "document.querySelectorAll('img').forEach(i => i.loading = 'eager');"
                "window.scrollTo(0, document.body.scrollHeight);"
            )
            deadline = time.monotonic() + LOAD_TIMEOUT
            while driver.execute_script(_PENDING_IMAGES):
                if time.monotonic() > deadline:
                    yield f"{page}: images still loading after {LOAD_TIMEOUT:.0f} s"
                    break
                time.sleep(0.1)
            n_images = driver.execute_script("return document.images.length;")
            for src in driver.execute_script(_BROKEN_IMAGES):
                yield f"{page}: image did not load: {src}"
            for entry in driver.get_log("browser"):
                if entry.get("level") == "SEVERE":
                    yield f"{page}: console error: {entry.get('message')}"
            print(f"  {page}: {n_images} images", file=sys.stderr)
    finally:
        driver.quit()
        server.shutdown()
        server.server_close()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--html", type=Path, default=DEFAULT_HTML, help="the built site")
    parser.add_argument(
        "--page",
        action="append",
        dest="pages",
        help="a page to open in the browser, relative to --html (repeatable; default: "
        + ", ".join(DEFAULT_PAGES)
        + ")",
    )
    parser.add_argument("--no-browser", action="store_true", help="check the links only")
    args = parser.parse_args(argv)
    html: Path = args.html
    if not (html / "index.html").is_file():
        print(f"check_docs_pages: no site at {html} (build it first)", file=sys.stderr)
        return 1
    errors = list(link_errors(html))
    n_pages = sum(1 for _ in html.rglob("*.html"))
    print(f"links: {n_pages} pages, {len(errors)} problems", file=sys.stderr)
    if not args.no_browser:
        pages = args.pages or list(DEFAULT_PAGES)
        found = list(browser_errors(html, pages))
        print(f"browser: {len(pages)} pages, {len(found)} problems", file=sys.stderr)
        errors += found
    for error in errors:
        print(error, file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
