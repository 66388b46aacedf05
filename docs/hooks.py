"""MkDocs build hooks: the tutorials and the home-page figure come from the library itself.

- Every notebook of ``notebooks/`` is executed top to bottom (nbclient) into
  ``docs/tutorials/`` (git-ignored) unless a copy executed from the same inputs
  (the notebook, the library's sources, the shipped data) is there; a failing
  cell fails the build. This is where the notebooks run in
  CI: ``make test`` builds the site.
- ``docs/assets/generated/home_localization.png`` (git-ignored) is drawn by
  localizing one query of the shipped sample scenario.
- Maths is rendered at build time: the TeX that ``pymdownx.arithmatex`` (generic mode)
  leaves in ``<span/div class="arithmatex">`` becomes MathML (``latex2mathml``), which
  browsers draw natively, so the site needs no script and no network to show formulas.
- The notebook pages' template (mkdocs-jupyter, nbconvert's lab template) carries a module
  script that imports mermaid from a CDN when the page holds a mermaid diagram; the
  tutorials hold none, so the script is dropped from pages without one (the built site
  then references no CDN; ``tests/docs/test_site.py`` checks it).
- The theme's script bundle names two scripts it loads only on demand from unpkg.com: a
  ResizeObserver polyfill (for browsers without ResizeObserver) and mermaid (for pages with a
  mermaid diagram). After the build both URLs are pointed into the site itself: the polyfill is
  vendored in ``docs/assets/vendor/`` (resize-observer-polyfill 1.5.1, MIT, its licence beside it);
  mermaid is not (this site draws no diagram), so a page with a mermaid diagram fails the build
  instead of fetching it from a CDN.
"""

from __future__ import annotations

import hashlib
import html
import logging
import os
import re
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("mkdocs.hooks.factorloc")
DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
NOTEBOOKS = REPO / "notebooks"
TUTORIALS = DOCS / "tutorials"
GENERATED = DOCS / "assets" / "generated"


def on_pre_build(config: Any, **kwargs: Any) -> None:
    execute_notebooks()
    home_figure()


_MATH = re.compile(r'<(span|div) class="arithmatex">(.*?)</\1>', re.S)
_DELIMITERS = {"\\(": ("\\)", "inline"), "\\[": ("\\]", "block")}


def _mathml(match: re.Match[str]) -> str:
    from latex2mathml.converter import convert

    tag, body = match.group(1), html.unescape(match.group(2)).strip()
    for opening, (closing, display) in _DELIMITERS.items():
        if body.startswith(opening) and body.endswith(closing):
            tex = body[len(opening) : -len(closing)].strip()
            return f'<{tag} class="arithmatex">{convert(tex, display=display)}</{tag}>'
    raise ValueError(f"unexpected arithmatex output: {body[:80]!r}")


def render_maths(page_html: str) -> str:
    """Replace arithmatex's TeX by MathML (see the module docstring)."""
    return _MATH.sub(_mathml, page_html)


def on_page_content(page_html: str, **kwargs: Any) -> str:
    return render_maths(page_html)


_MERMAID_LOADER = re.compile(r'<script type="module">(?:(?!</script>).)*?mermaid\.esm\.min\.mjs.*?</script>', re.S)


_MERMAID_DIAGRAM = re.compile(r'<[a-z]+ [^>]*class="[^"]*\bjp-Mermaid\b')


_THEME_MERMAID_DIAGRAM = re.compile(r'<(?:pre|div) [^>]*class="[^"]*\bmermaid\b')


def on_post_page(output: str, **kwargs: Any) -> str:
    page = kwargs.get("page")
    if _THEME_MERMAID_DIAGRAM.search(output):
        raise ValueError(f"{getattr(page, 'url', '?')}: a mermaid diagram, but the site bundles no mermaid (docs/hooks.py)")
    if _MERMAID_DIAGRAM.search(output):
        return output
    return _MERMAID_LOADER.sub("", output)


#: The theme bundle's on-demand CDN scripts → where they live in the built site, relative to the bundle
#: (``assets/javascripts/``); resolved at run time against the bundle's own address, so it works at any
#: page depth and from ``file://``.
BUNDLE_ON_DEMAND = {
    "https://unpkg.com/resize-observer-polyfill": "../vendor/resize-observer-polyfill/ResizeObserver.js",
    "https://unpkg.com/mermaid@11/dist/mermaid.min.js": "../vendor/mermaid/mermaid.min.js",
}


def localize_bundle(bundle_js: str) -> str:
    """The theme's bundle with its on-demand CDN URLs replaced by the site's own copies."""
    for url, local in BUNDLE_ON_DEMAND.items():
        here = f'new URL("{local}",document.querySelector(\'script[src*="javascripts/bundle."]\').src).href'
        bundle_js = bundle_js.replace(f'"{url}"', here)
    return bundle_js


def on_post_build(config: Any, **kwargs: Any) -> None:
    for bundle in (Path(config["site_dir"]) / "assets" / "javascripts").glob("bundle.*.min.js"):
        bundle.write_text(localize_bundle(bundle.read_text()))


def _inputs_digest(source: Path) -> str:
    """A hash of everything a notebook's outputs depend on: itself, the library and the shipped data."""
    h = hashlib.sha256(source.read_bytes())
    for path in sorted([*(REPO / "factorloc").rglob("*.py"), *(REPO / "data").rglob("*.yaml")]):
        h.update(str(path.relative_to(REPO)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def execute_notebooks() -> None:
    """Execute each notebook into docs/tutorials/ unless an executed copy of the same inputs exists."""
    import nbformat
    from nbclient import NotebookClient

    TUTORIALS.mkdir(parents=True, exist_ok=True)
    force = os.environ.get("FACTORLOC_DOCS_REEXECUTE") == "1"
    for source in sorted(NOTEBOOKS.glob("*.ipynb")):
        target = TUTORIALS / source.name
        digest = _inputs_digest(source)
        if not force and target.exists():
            done = nbformat.read(target, as_version=4).metadata.get("factorloc_inputs_sha256")
            if done == digest:
                continue
        t0 = time.perf_counter()
        nb = nbformat.read(source, as_version=4)
        NotebookClient(nb, timeout=900, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
        nb.metadata["factorloc_inputs_sha256"] = digest
        nbformat.write(nb, target)
        log.info("executed %s in %.1f s", source.name, time.perf_counter() - t0)


def home_figure() -> None:
    """A floor plan with one localized pose and its 95 % covariance ellipse (scaled up to be visible)."""
    target = GENERATED / "home_localization.png"
    if target.exists():
        return
    import math

    import matplotlib

    matplotlib.use("Agg")  # this process only: the notebook kernels keep their inline backend
    import matplotlib.pyplot as plt

    import factorloc
    from factorloc.datasets import load_scenario
    from factorloc.plotting import plot_covariance_ellipse_on_axes, plot_world_on_axes

    scenario = load_scenario(REPO / "data" / "sample")
    localizer = factorloc.Localizer(scenario.reference)
    case = next(q for q in scenario.queries if q.truth is not None and not q.faults)
    loc = localizer.localize(case.query)
    fig, ax = plt.subplots(figsize=(7.5, 6.0), dpi=110)
    plot_world_on_axes(ax, scenario.world)
    ref = scenario.reference.T_world_reference
    ax.plot(ref.x, ref.y, marker="*", ms=14, color="black", ls="", label="reference (panorama + 3D scan)")
    ax.plot(case.truth.x, case.truth.y, "o", ms=7, mfc="none", mec="#1b4965", label="true pose")
    ax.plot(loc.pose.x, loc.pose.y, "x", ms=8, color="#d1495b", label="factorloc estimate")
    arrow = 0.45
    ax.annotate(
        "",
        xy=(loc.pose.x + arrow * math.cos(loc.pose.theta), loc.pose.y + arrow * math.sin(loc.pose.theta)),
        xytext=(loc.pose.x, loc.pose.y),
        arrowprops={"arrowstyle": "-|>", "color": "#d1495b"},
    )
    if not loc.undetermined:
        scale = 20.0
        plot_covariance_ellipse_on_axes(
            ax, (loc.pose.x, loc.pose.y), loc.covariance[:2, :2] * scale**2, lw=1.5, label=f"95 % covariance ellipse ×{scale:.0f}"
        )
    sx, sy, st = loc.sigmas
    ax.set_title(f"query {case.id}: σx {100 * sx:.1f} cm, σy {100 * sy:.1f} cm, σθ {math.degrees(st):.2f}°")
    ax.legend(loc="upper right", fontsize=8)
    GENERATED.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, bbox_inches="tight")
    plt.close(fig)
