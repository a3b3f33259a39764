"""The reports in a real browser, offline: every table and every figure renders.

Headless Chromium (Debian's package, which `make test` installs when it can) is driven
by Playwright. Any request other than the report file itself is blocked and recorded: a
self-contained report makes none.
"""

from __future__ import annotations

import importlib.util
import shutil

import pytest

from .conftest import needs

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [needs({"chromium": CHROMIUM is not None,
                     "playwright": importlib.util.find_spec("playwright") is not None},
                    "Debian's chromium, which make test installs where it can; playwright: a test extra"),
              pytest.mark.slow]   # on the workflow's fleet run


@pytest.fixture(scope="module")
def browser():
    from playwright import sync_api
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run",
            "--host-resolver-rules=MAP * ~NOTFOUND"])
        yield b
        b.close()


def open_offline(browser, path):
    context = browser.new_context(viewport={"width": 1300, "height": 900})
    outside = []

    def guard(route):
        if route.request.url.startswith("file://"):
            route.continue_()
        else:
            outside.append(route.request.url)
            route.abort()
    context.route("**/*", guard)  # every page of this context, links followed included
    page = context.new_page()
    page.goto(path.as_uri(), wait_until="load")
    return page, outside


def figures_rendered(page) -> list[dict]:
    """Size of every inline figure and whether its embedded raster layers decoded."""
    return page.evaluate("""() => Array.from(document.querySelectorAll('figure svg')).map(svg => {
        const box = svg.getBoundingClientRect();
        const images = Array.from(svg.querySelectorAll('image'));
        return {width: box.width, height: box.height, images: images.length,
                rasters_ok: images.every(i => i.getBBox().width > 0 &&
                    (i.getAttribute('href') || i.getAttribute('xlink:href') || '').startsWith('data:image/png'))};
    })""")


def test_unit_report_renders_offline(fleet_run, browser, tmp_path):
    page, outside = open_offline(browser, fleet_run / "reports" / "B1" / "A1" / "2026-01-01.html")
    for table in ("#counts", "#noise-terms", "#table-hold-means", "#table-samples", "#table-by-temperature",
                  "#excess", "#covariates", "#candidates", "#ladder-table", "#provenance-table"):
        rows = page.locator(f"{table} tr")
        assert rows.count() >= 2, table
        assert page.locator(table).bounding_box()["height"] > 20, table
    assert page.locator("#table-hold-means tr").count() == 2 + 9  # two header rows, 3 x 3
    figures = figures_rendered(page)
    assert len(figures) == 9  # timeline, Allan deviation, parameters, by temperature, 2 error
    # maps, residuals, heat maps, ladder
    for f in figures:
        assert f["width"] > 200 and f["height"] > 150 and f["rasters_ok"], f
    assert "leave-temperature-out RMS" in page.locator("#verdict").inner_text()
    page.screenshot(path=str(tmp_path / "unit.png"), full_page=True)
    assert (tmp_path / "unit.png").stat().st_size > 50_000
    assert outside == []


def test_fleet_report_renders_offline_and_links_every_unit(fleet_run, browser, tmp_path):
    page, outside = open_offline(browser, fleet_run / "reports" / "index.html")
    rows = page.locator("table.units tr")
    assert rows.count() == 3 + 7  # a header per batch
    assert page.locator("tr.failed").count() == 2
    figures = figures_rendered(page)
    # 11 histograms and the outliers' distributions
    assert len(figures) == 12 and all(f["width"] > 100 for f in figures)
    links = page.locator("table.units a").evaluate_all("as => as.map(a => a.href)")
    assert len(links) == 7
    for href in links:
        target = page.context.new_page()
        target.goto(href)
        assert target.locator("h1").count() == 1
        target.close()
    page.screenshot(path=str(tmp_path / "fleet.png"), full_page=True)
    assert outside == []
