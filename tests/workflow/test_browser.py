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
pytestmark = [
    needs(
        {"chromium": CHROMIUM is not None, "playwright": importlib.util.find_spec("playwright") is not None},
        "Debian's chromium, which make test installs where it can; playwright: a test extra",
    ),
    pytest.mark.slow,
]  # on the workflow's fleet run


@pytest.fixture(scope="module")
def browser():
    from playwright import sync_api

    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(
            executable_path=CHROMIUM,
            args=[
                "--no-sandbox",
                "--disable-gpu",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
                "--host-resolver-rules=MAP * ~NOTFOUND",
            ],
        )
        yield b
        b.close()


def open_offline(browser, path, viewport=(1300, 900)):
    context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
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
    for table in (
        "#counts",
        "#noise-terms",
        "#table-hold-means",
        "#table-samples",
        "#table-by-temperature",
        "#excess",
        "#covariates",
        "#candidates",
        "#ladder-table",
        "#provenance-table",
    ):
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


# The worst cases of a fleet summary's rows: names as long as the manifest allows (64
# characters; a batch name may hold spaces), a failed unit's long one-line error, a unit
# with several plausibility warnings.
LONG_DEVICE = "IMU-7-line-3_station-12.rev-C_serial-0000001234567890-calib.retry"[:64]
LONG_BATCH = "lot 2026-W03 Munich line 7 night shift rework after supplier change"[:64]
LONG_ERROR = (
    "the log's mount column names orientations the protocol does not define ('+x+y', "
    "'-z?', 'tilt 45'); expected one of +x, -x, +y, -y, +z, -z for every hold; rows 120 "
    "to 98 304 of the log are affected, so no hold can be assigned a known rate and the "
    "segmentation has nothing to calibrate on (check the rig's export settings)"
)
WARNINGS = (
    (
        "protocol_unbalanced",
        "the protocol is unbalanced: mount -z is missing while ±x, ±y have both: "
        "errors that a balanced protocol averages out (a g-sensitivity, a scale asymmetry) go into "
        "the fitted terms",
    ),
    (
        "temperature_stuck",
        "temp reads exactly 24.5 °C for 1800 s from t = 3600 s, although it "
        "resolves steps of 0.0625 °C elsewhere: a stuck sensor; holds in that stretch are "
        "calibrated at a temperature the unit may not have had",
    ),
    (
        "sample_jitter",
        "3.2% of the sample intervals differ from the nominal 0.01 s by over 10%: "
        "timestamps from a jittery clock; rates and hold boundaries are still computed from them",
    ),
    (
        "holds_rejected",
        "7 of 120 holds were rejected (gyro_disagrees: 2, not_steady: 5): the "
        "calibration rests on the rest; the report's segment list shows each one",
    ),
)


def worst_case_fleet_summary(fleet_run, out):
    """The fleet summary of the workflow's fleet run, read from its unit files as the fleet
    job reads them (servo, sweep, a turntable unit twice, two failed units), with device A2
    and batch B2 renamed to 64 characters, BAD's error made long and A1's first session given
    four warnings; its unit links go to the run's unit reports."""
    import csv

    import yaml

    from gyrocal.fleet.summary import FleetSettings, fleet_summary, write_fleet_report
    from gyrocal.io.plausibility import finding

    units = []
    with open(fleet_run / "devices.tsv", newline="") as f:
        for row in csv.DictReader(f, delimiter="\t"):
            folder = fleet_run / "results" / row["batch"] / row["device"] / row["session"]
            report = fleet_run / "reports" / row["batch"] / row["device"] / f"{row['session']}.html"
            row.update(
                device=LONG_DEVICE if row["device"] == "A2" else row["device"],
                batch=LONG_BATCH if row["batch"] == "B2" else row["batch"],
            )
            units.append({"row": row, "folder": folder, "report": report.as_uri()})
    settings = FleetSettings.from_dict(yaml.safe_load((fleet_run / "config.yaml").read_text()))
    summary = fleet_summary(units, settings)
    for row in summary["rows"]:
        if row["device"] == "BAD":
            row["error"] = LONG_ERROR
        if (row["device"], row["session"]) == ("A1", "2026-01-01"):
            row["warnings"] = [finding(code, message) for code, message in WARNINGS]
    write_fleet_report(summary, out / "index.html", settings)
    return out / "index.html"


def test_fleet_summary_fits_a_1400_px_screen(fleet_run, browser, tmp_path):
    """At 1400 px the fleet summary does not scroll sideways, no table is wider than the
    window and every row is one line; long texts are clipped, in full in the row's
    disclosure and its title."""
    from PIL import Image

    index = worst_case_fleet_summary(fleet_run, tmp_path)
    page, outside = open_offline(browser, index, viewport=(1400, 900))
    protocols = page.locator("table.units td:nth-child(3)").all_inner_texts()
    assert sorted(set(protocols)) == ["servo", "sweep", "turntable"] and protocols.count("turntable") == 5

    def fits():
        return page.evaluate("""() => ({
            scroll: Math.max(document.documentElement.scrollWidth, document.body.scrollWidth),
            tables: Array.from(document.querySelectorAll('table')).filter(t => t.checkVisibility())
                .map(t => t.getBoundingClientRect().right),
            panels: Array.from(document.querySelectorAll('details[open] > div')).map(d => {
                const b = d.getBoundingClientRect(); return [b.left, b.right]; })})""")

    layout = fits()
    assert layout["scroll"] <= 1400 and len(layout["tables"]) == 3 + 2  # units; yield, drift
    assert all(0 < right <= 1400 for right in layout["tables"]), layout

    # every body row of a table one line tall (an unopened disclosure included)
    def row_heights(selector):
        return page.evaluate(
            """s => Array.from(document.querySelectorAll(s)).map(r => ({
            height: r.getBoundingClientRect().height,
            line: parseFloat(getComputedStyle(r.cells[0]).lineHeight)}))""",
            selector,
        )

    rows = row_heights("table.units tbody tr, #yield-table tr:not(:first-child), #drift-table tbody tr")
    assert len(rows) == 7 + 2 + 1
    assert all(r["height"] < 2 * r["line"] for r in rows), rows
    # clipped, with the whole text in a title and a disclosure per row
    link = page.locator("table.units a", has_text="IMU-7-line")
    assert link.get_attribute("title") == LONG_DEVICE
    assert link.evaluate("a => a.scrollWidth > a.clientWidth")
    assert (
        page.locator("table.units tbody tr").count()
        == page.locator("table.units tbody tr details").count()
        == 7
    )
    bad = page.locator("tr.failed", has_text="BAD").locator("details")
    summary = bad.locator("summary")
    assert summary.get_attribute("title") == f"segment: {LONG_ERROR}"
    assert summary.evaluate("s => s.scrollWidth > s.clientWidth")  # clipped to one line
    assert not bad.locator("div").is_visible()
    summary.click()  # open it: the whole error
    assert bad.locator("div").is_visible() and LONG_ERROR in bad.locator("div").inner_text()
    warned = page.locator("table.units tbody tr").first
    assert warned.locator("td").nth(8).inner_text() == "4"  # after "since the last model"
    warned.locator("summary").click()
    text = warned.locator("details > div").inner_text()
    assert "4 warnings: protocol_unbalanced, temperature_stuck, sample_jitter, holds_rejected" in text
    assert all(message in text for _, message in WARNINGS) and "× expected" in text
    for d in page.locator("details.table").all():  # the parameter tables
        d.locator("summary").click()
    layout = fits()
    assert layout["scroll"] <= 1400 and len(layout["tables"]) == 2 * 3 + 2, layout
    assert all(0 < right <= 1400 for right in layout["tables"]), layout
    assert len(layout["panels"]) == 2 and all(0 <= left < right <= 1400 for left, right in layout["panels"])
    rows = row_heights("table.parameters tbody tr")
    assert len(rows) == 5 and all(r["height"] < 2 * r["line"] for r in rows), rows
    shot = tmp_path / "fleet-1400.png"
    page.screenshot(path=str(shot), full_page=True)
    with Image.open(shot) as image:
        assert image.width == 1400 and len(image.convert("RGB").getcolors(1 << 24)) > 100
    assert outside == []


REPO_ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def hand_rotation_report(tmp_path_factory):
    """The unit report of the real hand-rotation recording (the demo's IMU1) as the workflow
    makes it: imported, segmented, analysed and reported by the stage commands."""
    from gyrocal.run.cli import main

    d = tmp_path_factory.mktemp("ferraris")
    real = REPO_ROOT / "data" / "real" / "imucal-ferraris"
    unit = ["--device", "IMU1", "--batch", "R1", "--session", "2018-01-01", "--protocol", "ferraris"]
    for argv in (
        [
            "import",
            str(real / "session.csv"),
            "--map",
            str(real / "import.yaml"),
            "-o",
            str(d / "imucal.parquet"),
        ],
        ["segment", str(d / "imucal.parquet"), "--out", str(d / "unit"), *unit],
        ["analyse", str(d / "unit"), *unit],
        ["report", str(d / "unit"), "-o", str(d / "IMU1.html"), *unit],
    ):
        assert main(argv) == 0, argv
    return d / "IMU1.html"


@pytest.fixture(scope="module")
def papers_page(tmp_path_factory):
    """The papers' page (`gyrocal paper --quick`: every seed's tables and figures)."""
    from gyrocal.run.cli import main

    out = tmp_path_factory.mktemp("paper")
    assert main(["paper", "--out", str(out), "--quick"]) == 0
    return out / "index.html"


# What may not pass the right edge of a 1400 px window: the page itself and every block that
# holds data (a table, a figure, a pre, a disclosure's summary line).
WIDTHS = """() => ({
    scroll: Math.max(document.documentElement.scrollWidth, document.body.scrollWidth),
    beyond: Array.from(document.querySelectorAll('table, figure, pre, summary, h1, h2, p'))
        .filter(e => e.getBoundingClientRect().right > 1400)
        .map(e => `${e.tagName.toLowerCase()}#${e.id} ${Math.round(e.getBoundingClientRect().right)} px`)})"""


def test_no_page_of_a_demo_run_is_wider_than_1400_px(
    fleet_run, browser, hand_rotation_report, papers_page, tmp_path
):
    """Every page the workflow writes, at a 1400 px window, with its disclosures closed and
    open: the unit reports of every protocol, the failed units' pages, the drift page, the
    fleet summary and the papers' page. Long values wrap or open in full from a clipped line;
    the wide parameter grid comes as tables of eight temperature points."""
    from PIL import Image

    pages = sorted((fleet_run / "reports").rglob("*.html")) + [hand_rotation_report, papers_page]
    context = browser.new_context(viewport={"width": 1400, "height": 900})
    context.route(
        "**/*", lambda route: route.continue_() if route.request.url.startswith("file://") else route.abort()
    )
    page = context.new_page()
    kinds = []
    for path in pages:
        page.goto(path.as_uri(), wait_until="load")
        heading = page.locator("h1").inner_text()
        kinds.append(
            page.locator("p.small").first.inner_text().rsplit("protocol ", 1)[-1]
            if heading.startswith("Calibration of")
            else "failed"
            if page.locator("p.failed").count()
            else heading.split(" ")[0].lower()
        )
        closed = page.evaluate(WIDTHS)
        count = page.evaluate(
            "() => { const d = document.querySelectorAll('details');"
            " d.forEach(x => x.open = true); return d.length; }"
        )
        opened = page.evaluate(WIDTHS)
        for state, layout in (("closed", closed), ("open", opened)):
            assert layout["scroll"] <= 1400 and not layout["beyond"], (path, state, layout)
        if heading.startswith("Calibration of"):
            assert count >= 1, path  # the reproduce command at least
    # every protocol's unit report, two failed units, the drift page, the fleet and papers' pages
    assert sorted(kinds) == sorted(
        ["turntable"] * 3 + ["servo", "sweep", "ferraris", "failed", "failed", "drift", "fleet", "seed"]
    ), kinds
    # the long reproduce command is one clipped line until opened
    page.goto(pages[0].as_uri(), wait_until="load")
    command = page.locator("#provenance-table details.long summary")
    assert command.evaluate("s => s.scrollWidth > s.clientWidth")
    line = float(command.evaluate("s => parseFloat(getComputedStyle(s).lineHeight)"))
    assert command.bounding_box()["height"] < 2 * line
    command.click()
    assert command.bounding_box()["height"] > 3 * line and command.evaluate(
        "s => s.scrollWidth <= s.clientWidth"
    )
    shot = tmp_path / "unit-1400.png"
    page.screenshot(path=str(shot), full_page=True)
    with Image.open(shot) as image:
        assert image.width == 1400
    context.close()


@pytest.fixture(scope="module")
def zoo_reports(tmp_path_factory):
    """Unit reports of units from the independent zoo whose diagnoses print the longest
    terms (a power law of time, profiled; a table of the turning axis's rate on the other
    outputs), made by the stage commands with the other session, as the workflow makes them."""
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.run.cli import main

    d = tmp_path_factory.mktemp("zoo_reports")
    pages = []
    for effect in ("warmup_power_law", "cross_axis_quadratic"):
        unit = make_unit(effect=effect, protocol="turntable3", noise="white", seed=1)
        meta = ["--device", effect, "--batch", "Z", "--protocol", "turntable"]
        for s in (0, 1):
            write_session(unit, d / f"{effect}-{s}.parquet", session=s, seed=1000 + s, rate_hz=10.0)
            assert (
                main(
                    [
                        "segment",
                        str(d / f"{effect}-{s}.parquet"),
                        "--out",
                        str(d / f"{effect}-{s}"),
                        "--session",
                        f"2026-01-0{s + 1}",
                        *meta,
                    ]
                )
                == 0
            )
        assert (
            main(
                [
                    "analyse",
                    str(d / f"{effect}-0"),
                    "--other-session",
                    str(d / f"{effect}-1"),
                    "--session",
                    "2026-01-01",
                    *meta,
                ]
            )
            == 0
        )
        assert (
            main(
                [
                    "report",
                    str(d / f"{effect}-0"),
                    "-o",
                    str(d / f"{effect}.html"),
                    "--session",
                    "2026-01-01",
                    *meta,
                ]
            )
            == 0
        )
        pages.append(d / f"{effect}.html")
    return pages


def test_reports_with_the_longest_formulas_fit_a_1400_px_window(browser, zoo_reports):
    """The diagnosis' terms read as formulas, and their config spelling wraps: no zoo unit's
    report is wider than a 1400 px window, disclosures closed or open (a candidates table
    with such terms was 2,099 px wide)."""
    context = browser.new_context(viewport={"width": 1400, "height": 900})
    context.route(
        "**/*", lambda route: route.continue_() if route.request.url.startswith("file://") else route.abort()
    )
    page = context.new_page()
    for path in zoo_reports:
        page.goto(path.as_uri(), wait_until="load")
        assert page.locator("#candidates").count() == 1
        closed = page.evaluate(WIDTHS)
        page.evaluate("() => document.querySelectorAll('details').forEach(x => x.open = true)")
        opened = page.evaluate(WIDTHS)
        for state, layout in (("closed", closed), ("open", opened)):
            assert layout["scroll"] <= 1400 and not layout["beyond"], (path, state, layout)
    context.close()
