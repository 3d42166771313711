"""Open the built documentation site in a headless Chromium and check what a reader meets.

Usage: ``python tools/check_site_in_browser.py [docs/_build/html]`` after ``make docs``.
Needs a Chromium on the PATH (``chromium``; Debian: ``apt install chromium``); it is not
a dependency of czmpc and this check is not part of ``make test``.

Checks, each printed with what was found:

1. the landing page renders (JavaScript run) with its title and the navigation to the
   getting-started page, every guide, the references, the API and the gallery;
2. every navigation link of the landing page leads to a file that exists;
3. the search page, given ``?q=hammerstein``, lists results once its JavaScript has
   loaded the search index (Sphinx fills ``#search-results`` in the browser).

Exit 0 when all hold, 1 otherwise.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

#: Pages the landing page must link to (paths relative to the site root).
REQUIRED_LINKS = ("getting_started.html", "guides/identify.html", "guides/commission.html",
                  "guides/tune.html", "guides/plant_link.html", "guides/campaigns.html",
                  "guides/regress.html", "api/index.html", "auto_examples/index.html")


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.hrefs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "a":
            href = dict(attrs).get("href")
            if href:
                self.hrefs.append(href)


def rendered_dom(browser: str, url: str) -> str:
    """The DOM of ``url`` after its scripts ran (headless, 10 s of virtual time)."""
    proc = subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
         "--virtual-time-budget=10000", "--dump-dom", url],
        capture_output=True, text=True, timeout=120, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{browser} failed on {url}: {proc.stderr[-500:]}")
    return proc.stdout


def main(argv: list[str]) -> int:
    site = Path(argv[0] if argv else "docs/_build/html").resolve()
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("no chromium on the PATH (apt install chromium)", file=sys.stderr)
        return 1
    ok = True
    landing = rendered_dom(browser, (site / "index.html").as_uri())
    title = re.search(r"<title>(.*?)</title>", landing, re.S)
    print(f"landing page title: {title.group(1).strip() if title else None!r}")
    ok &= title is not None and "czmpc" in title.group(1)
    parser = _Links()
    parser.feed(landing)
    local = sorted({h.split("#")[0] for h in parser.hrefs
                    if h and not h.startswith(("http:", "https:", "mailto:", "#"))})
    missing_required = [r for r in REQUIRED_LINKS if r not in local]
    broken = [h for h in local if h and not (site / h).is_file()]
    print(f"landing page: {len(local)} local links; required missing: {missing_required}; "
          f"broken: {broken}")
    ok &= not missing_required and not broken
    search = rendered_dom(browser, (site / "search.html").as_uri() + "?q=hammerstein")
    hits = re.findall(r'<li[^>]*>\s*<a[^>]+href="([^"]+)"', search.split('id="search-results"', 1)[-1])
    print(f"search 'hammerstein': {len(hits)} results, first {hits[:3]}")
    ok &= len(hits) > 0
    print("site check:", "OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
