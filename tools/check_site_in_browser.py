"""Open the built documentation site in a headless Chromium and check what a reader meets.

Usage: ``python tools/check_site_in_browser.py [docs/_build/html]`` after ``make docs``.
Needs a Chromium on the PATH (``chromium``; Debian: ``apt install chromium``); it is not
a dependency of czmpc and this check is not part of ``make test``.

Checks, each printed with what was found:

1. the landing page renders (JavaScript run) with its title and the navigation to the
   getting-started page, every guide, the references, the API and the gallery;
2. every navigation link of the landing page leads to a file that exists;
3. the search page, given ``?q=hammerstein``, lists results once its JavaScript has
   loaded the search index (Sphinx fills ``#search-results`` in the browser);
4. an API page: `czmpc.OffsetFreeMPC.step` has a page of its own, the class page links
   to it, and its Parameters section lists each parameter of the method with a
   description that gives its unit, and a Returns section.

Exit 0 when all hold, 1 otherwise.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

#: The API page the check opens, the class page that must link to it, and what its
#: Parameters section must list (each with its unit in the description).
API_PAGE = "api/generated/czmpc.OffsetFreeMPC.step.html"
API_CLASS_PAGE = "api/generated/czmpc.OffsetFreeMPC.html"
API_PARAMETERS = {"power_kw": "[kW]", "setpoint_kw": "[kW]", "applied_triac_pct": "[%]",
                  "setpoint_preview_kw": "[kW]", "grid_voltage_factor": "[-]"}

#: Pages the landing page must link to (paths relative to the site root).
REQUIRED_LINKS = ("getting_started.html", "guides/identify.html", "guides/commission.html",
                  "guides/tune.html", "guides/plant_link.html", "guides/campaigns.html",
                  "guides/regress.html", "guides/controller_failures.html", "reference/cli.html",
                  "api/index.html", "auto_examples/index.html", "development.html")


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


def rendered_parameters(dom: str) -> dict[str, str]:
    """The Parameters field of a rendered API page: each parameter with its description."""
    # from the Parameters field's title to the next field's (Returns) or the list's end
    field = re.search(r'<dt class="field-\w+">Parameters.*?</dt>(.*?)(?:<dt class="field-|\Z)', dom, re.S)
    if field is None:
        return {}
    entries = re.findall(r"<dt><strong>(\w+)</strong>.*?</dt>\s*<dd>(.*?)</dd>", field.group(1), re.S)
    return {name: re.sub(r"<[^>]+>", "", text) for name, text in entries}


def parameters_without_unit(params: dict[str, str]) -> list[str]:
    """The parameters of `API_PARAMETERS` missing from ``params`` or described without their unit."""
    return [name for name, unit in API_PARAMETERS.items() if unit not in params.get(name, "")]


def check_api_page(browser: str, site: Path) -> bool:
    """Check 4: the method page of `czmpc.OffsetFreeMPC.step`, as a browser renders it."""
    page = site / API_PAGE
    if not page.is_file():
        print(f"API page {API_PAGE}: missing")
        return False
    dom = rendered_dom(browser, page.as_uri())
    params = rendered_parameters(dom)
    wrong = parameters_without_unit(params)
    has_returns = re.search(r'<dt class="field-\w+">Returns', dom) is not None
    class_dom = rendered_dom(browser, (site / API_CLASS_PAGE).as_uri())
    linked = Path(API_PAGE).name in class_dom
    print(f"API page {API_PAGE}: parameters {sorted(params)}; missing or without unit: {wrong}; "
          f"Returns section: {has_returns}; linked from the class page: {linked}")
    return not wrong and has_returns and linked


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
    ok &= check_api_page(browser, site)
    print("site check:", "OK" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
