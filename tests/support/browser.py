"""A real headless Chromium for page tests: the DOM after the page's scripts ran, and screenshots.

    from support.browser import CHROMIUM, dump_dom, screenshot, elements

    dom = dump_dom(page_path, fragment="object=P37:pot")   # file:///...page.html#object=P37:pot
    html = elements(dom, "html")[0]                          # (tag, attrs) of every <html>
    assert html["data-errors"] == ""

Each run gets a fresh profile directory, and every network feature Chromium has is turned off
(the pages under test must need none). `CHROMIUM` is None when no Chromium is installed
(`.ci/run` installs the Debian package); tests skip with that reason.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from html.parser import HTMLParser
from pathlib import Path

__all__ = ["CHROMIUM", "NO_CHROMIUM", "dump_dom", "elements", "screenshot"]

CHROMIUM = next((p for p in map(shutil.which, ("chromium", "chromium-browser", "google-chrome")) if p), None)
NO_CHROMIUM = "no Chromium installed (apt-get install -y chromium; .ci/run installs it)"
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    if CHROMIUM is None:
        raise RuntimeError(NO_CHROMIUM)
    with tempfile.TemporaryDirectory(prefix="memora-chromium-") as profile:
        proc = subprocess.run([CHROMIUM, *_FLAGS, f"--user-data-dir={profile}", *args], capture_output=True, text=True,
                              timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"chromium exited {proc.returncode}: {proc.stderr[-2000:]}")
    return proc


def _url(page: Path, fragment: str) -> str:
    return Path(page).resolve().as_uri() + (f"#{fragment}" if fragment else "")


def dump_dom(page: Path, fragment: str = "", size: tuple[int, int] = (1400, 1000), timeout: float = 90,
             settle_ms: int = 0) -> str:
    """The serialized DOM once the page has loaded (its inline scripts have run by then); with
    `settle_ms`, after that much virtual time more (images decoded, load handlers run)."""
    settle = [f"--virtual-time-budget={settle_ms}"] if settle_ms else []
    return _run([f"--window-size={size[0]},{size[1]}", *settle, "--dump-dom", _url(page, fragment)], timeout).stdout


def screenshot(page: Path, out: Path, fragment: str = "", size: tuple[int, int] = (1400, 1000), timeout: float = 90) -> Path:
    _run([f"--window-size={size[0]},{size[1]}", f"--screenshot={out}", _url(page, fragment)], timeout)
    return out


class _Collector(HTMLParser):
    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.found: list[tuple[str, dict]] = []

    def handle_starttag(self, tag, attrs):
        self.found.append((tag, {k: v or "" for k, v in attrs}))

    handle_startendtag = handle_starttag


def elements(dom: str, tag: str | None = None, **attrs) -> list[dict]:
    """The attributes of every element with this tag (any tag if None) whose attributes include
    `attrs` (underscores in names read as dashes: data_count='segments')."""
    parser = _Collector()
    parser.feed(dom)
    want = {k.replace("_", "-"): v for k, v in attrs.items()}
    return [a for t, a in parser.found if (tag is None or t == tag) and all(a.get(k) == v for k, v in want.items())]
