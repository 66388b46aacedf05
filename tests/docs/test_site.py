"""Smoke check of the built documentation site in headless Chromium.

``make test`` builds the site (``make docs``) before running the tests. The
check opens the home page and the first tutorial as a browser would (offline,
with the flags a closed network needs) and asserts that each page's main
heading and at least one rendered figure are there; it then opens every page
with the network cut (:mod:`cdp`, the DevTools protocol) and asserts that none
requests anything but its own files or fails a request, that the concepts page
shows its formulas as rendered maths, and that the API page shows the right
parameter types and links instead of raw Sphinx roles. Run alone (``pytest``), it
skips, saying why, when the site has not been built or no Chromium is installed;
under ``make test`` (which sets ``FACTORLOC_REQUIRE_SITE=1`` after building the
site and installing Chromium) either absence is a failure, so that the check
cannot pass by not running.
"""

from __future__ import annotations

import base64
import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import NoReturn

import pytest
from cdp import FLAGS, load_pages


def _unavailable(reason: str) -> NoReturn:
    """Skip when run alone; fail under ``make test``, which promised the site and the browser."""
    if os.environ.get("FACTORLOC_REQUIRE_SITE") == "1":
        pytest.fail(f"{reason} (FACTORLOC_REQUIRE_SITE=1: make test builds the site and installs Chromium first)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def site(repo_root: Path) -> Path:
    index = repo_root / "site" / "index.html"
    if not index.is_file():
        _unavailable(f"the documentation site is not built ({index} missing): run `make docs`")
    return index.parent


@pytest.fixture(scope="module")
def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    _unavailable("Chromium is not installed (Debian: apt-get install chromium; `make docs` installs it when it can)")


def _dom(chromium: str, page: Path, profile: Path) -> str:
    out = subprocess.run(
        [chromium, *FLAGS, f"--user-data-dir={profile}", "--virtual-time-budget=5000", "--dump-dom", page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return out.stdout


def _screenshot(chromium: str, page: Path, profile: Path, target: Path) -> bytes:
    subprocess.run(
        [chromium, *FLAGS, f"--user-data-dir={profile}", "--window-size=1280,1600", f"--screenshot={target}", page.as_uri()],
        capture_output=True,
        timeout=120,
        check=True,
    )
    return target.read_bytes()


def test_home_page_has_its_heading_and_the_library_drawn_figure(site: Path, chromium: str, tmp_path: Path) -> None:
    dom = _dom(chromium, site / "index.html", tmp_path / "profile")
    assert re.search(r"<h1[^>]*>\s*factorloc", dom), "the home page's main heading is missing"
    srcs = re.findall(r'<img[^>]*src="([^"]+\.png)"', dom)
    assert srcs, "the home page shows no figure"
    figure = site / srcs[0]
    assert figure.is_file() and figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
    shot = _screenshot(chromium, site / "index.html", tmp_path / "profile", tmp_path / "home.png")
    assert shot[:8] == b"\x89PNG\r\n\x1a\n" and len(shot) > 20_000


def test_quickstart_tutorial_is_rendered_with_its_output_figures(site: Path, chromium: str, tmp_path: Path) -> None:
    page = site / "tutorials" / "01_quickstart" / "index.html"
    assert page.is_file(), "the quickstart tutorial was not rendered"
    dom = _dom(chromium, page, tmp_path / "profile")
    assert re.search(r"<h1[^>]*>\s*Quickstart", dom), "the tutorial's main heading is missing"
    figures = re.findall(r'<img[^>]*src="data:image/png;base64,([A-Za-z0-9+/=]+)"', dom)
    assert figures, "the executed tutorial shows no figure"
    assert base64.b64decode(figures[0])[:8] == b"\x89PNG\r\n\x1a\n"


#: Hosts of content delivery networks and web fonts: none may appear in the built site's pages and styles.
CDN = re.compile(r"cdn\.jsdelivr\.net|cdnjs\.cloudflare\.com|unpkg\.com|fonts\.googleapis\.com|fonts\.gstatic\.com|polyfill\.io")


def test_the_theme_loads_its_polyfill_from_the_site_itself(site: Path) -> None:
    # the theme's bundle asks for a ResizeObserver polyfill on browsers without one: docs/hooks.py points it
    # into the site, where the vendored copy must be
    (bundle,) = (site / "assets" / "javascripts").glob("bundle.*.min.js")
    assert '"../vendor/resize-observer-polyfill/ResizeObserver.js"' in bundle.read_text()
    polyfill = site / "assets" / "vendor" / "resize-observer-polyfill" / "ResizeObserver.js"
    assert "global.ResizeObserver = factory()" in polyfill.read_text()


def _pages(site: Path) -> list[Path]:
    """Every page; not 404.html, whose links are absolute (a web server serves it at the site's root)."""
    return sorted(site.rglob("index.html"))


def test_the_built_site_references_no_cdn(site: Path) -> None:
    offenders = []
    for f in [*site.rglob("*.html"), *site.rglob("*.css"), *site.rglob("*.js")]:
        text = f.read_text(errors="replace")
        for m in CDN.finditer(text):
            offenders.append(f"{f.relative_to(site)}: ...{text[max(0, m.start() - 60) : m.end() + 40]}...")
    assert not offenders, "\n".join(offenders)


@pytest.fixture(scope="module")
def offline(site: Path, chromium: str, tmp_path_factory: pytest.TempPathFactory):
    """Every page of the site, loaded once with the network cut."""
    article = "(document.querySelector('article') ? document.querySelector('article').innerText : '')"
    block_maths = "Array.from(document.querySelectorAll('math[display=block]'))"
    localize_query_row = (
        "(() => { const s = document.getElementById('factorloc.localize'); if (!s) return null; "
        "const d = s.closest('div.doc') || s.parentElement.parentElement; "
        "const rows = Array.from(d.querySelectorAll('tr')).filter(r => r.querySelector('td code')); "
        "const row = rows.find(r => r.querySelector('td code').textContent.trim() === 'query'); "
        "return row ? row.innerText : null; })()"
    )
    probes = {
        "maths": "document.querySelectorAll('math').length",
        "maths_height": f"Math.min(...{block_maths}.map(m => m.getBoundingClientRect().height), 1e9)",
        "text": article,
        "h1": "(document.querySelector('h1') || {}).textContent || ''",
        "png_figures": "document.querySelectorAll('img[src^=\"data:image/png\"]').length",
        "links_to_api": "document.querySelectorAll('article a[href*=\"#factorloc.\"]').length",
        "query_type": localize_query_row,
    }
    loads = load_pages(chromium, _pages(site), tmp_path_factory.mktemp("cdp-profile"), probes)
    return {Path(load.url.removeprefix("file://")).relative_to(site).as_posix(): load for load in loads}


def test_every_page_loads_offline_without_a_failed_request(offline) -> None:
    problems = []
    for page, load in offline.items():
        outside = [u for u in load.requested if not u.startswith(("file://", "data:", "about:", "blob:"))]
        if outside:
            problems.append(f"{page} requests {outside}")
        if load.failed:
            problems.append(f"{page}: failed requests {load.failed}")
        if load.errors:
            problems.append(f"{page}: script errors {load.errors}")
    assert len(offline) >= 13
    assert not problems, "\n".join(problems)


def test_the_concepts_page_shows_rendered_maths_offline(offline) -> None:
    concepts = offline["concepts/index.html"].probes
    assert concepts["maths"] >= 4, "the concepts page shows no rendered formula"
    assert concepts["maths_height"] > 10, "a display formula was not laid out"
    raw = [d for d in ("\\[", "\\(", "$$") if d in concepts["text"]]
    assert len(concepts["text"]) > 5000 and not raw, f"raw TeX delimiters {raw} are left in the concepts page"


def test_the_api_page_shows_the_right_types_and_links_not_sphinx_roles(offline) -> None:
    api = offline["api/index.html"].probes
    assert api["query_type"] is not None and "Query" in api["query_type"] and "Reference" not in api["query_type"]
    roles = re.findall(r":(?:func|class|meth|mod|data|attr|exc):`[^`]*`", api["text"])
    assert len(api["text"]) > 100_000 and not roles, f"raw Sphinx roles on the API page: {roles[:5]}"
    assert api["links_to_api"] > 200


def test_a_tutorial_page_loads_offline_with_its_figures(offline) -> None:
    tutorial = offline["tutorials/05_real_laser_logs/index.html"].probes
    assert "laser" in tutorial["h1"].lower(), tutorial["h1"]
    assert tutorial["png_figures"] >= 1, "the executed tutorial shows no figure offline"
