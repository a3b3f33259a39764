"""A fleet summary that opens at any size: past PAGE_UNITS unit sessions the summary lists its
batches, each batch's rows on pages of their own; every unit is on exactly one page."""

from __future__ import annotations

import re
from html import unescape

import pytest

from gyrocal.fleet import summary as fleet


def rows(batches: dict[str, int]) -> list[dict]:
    out = []
    for batch, n in batches.items():
        for i in range(n):
            device = f"U{i:05d}"
            row = {
                "batch": batch,
                "device": device,
                "session": "2026-03-02",
                "protocol": "turntable",
                "report": f"{batch}/{device}/2026-03-02.html",
            }
            if i % 97 == 5:
                row.update(
                    status="failed", stage="segment", error="not a readable Parquet file", internal=False
                )
            else:
                row.update(
                    status="ok",
                    summary={"validation_rms": 0.01 + 1e-6 * i, "excess": 1.0, "excess_over_expected": 1.0},
                    warnings=[],
                    missing="nothing",
                    span=(-40.0, 80.0),
                    noise=None,
                    params={"scale.x": 100.0 + i},
                )
            out.append(row)
    return out


def write(tmp_path, table):
    ok = [r for r in table if r["status"] == "ok"]
    path = tmp_path / "reports" / "index.html"
    fleet.write_fleet_report({"rows": table, "ok": ok, "fleet": None, "servo_vs_turntable": []}, path)
    return path


def unit_links(html: str) -> list[str]:
    return [unescape(link) for link in re.findall(r'<a class="clip" href="([^"]+/2026-03-02\.html)"', html)]


def test_a_small_fleet_is_one_page(tmp_path):
    table = rows({"B1": 20, "B2": 7})
    path = write(tmp_path, table)
    html = path.read_text()
    assert sorted(unit_links(html)) == sorted(r["report"] for r in table)
    assert fleet.batch_pages_of(path) == []


def test_a_large_fleet_lists_its_batches_and_pages_every_unit_once(tmp_path):
    size = {"lot 7/α <night>": fleet.PAGE_UNITS * 2 + 300, "B2": 40}
    table = rows(size)
    # a batch whose reports lie where pages could go: named like the pages' old folder
    reports = tmp_path / "reports" / "batches" / "U1"
    reports.mkdir(parents=True)
    (reports / "2026-03-02.html").write_text("a unit's report")
    path = write(tmp_path, table)
    index = path.read_text()
    assert unit_links(index) == []  # no unit rows in the index
    assert "&lt;night&gt;" in index and "<night>" not in index  # the batch name escaped
    pages = fleet.batch_pages_of(path)
    assert len(pages) == 3 + 1
    linked = re.findall(r'href="(index-batch-[^"]+\.html)"', index)
    assert sorted(set(linked)) == sorted(p.name for p in pages)
    seen = []
    for page in pages:
        html = page.read_text()
        links = unit_links(html)
        assert len(links) <= fleet.PAGE_UNITS
        assert '<a href="index.html">Fleet summary</a>' in html
        seen += links
    assert sorted(seen) == sorted(r["report"] for r in table)
    # the index stays small whatever the fleet: a row per batch
    assert len(index.encode()) < 200_000

    # the same fleet smaller again: the pages of the larger one do not stay; reports do
    write(tmp_path, rows({"B2": 40}))
    assert fleet.batch_pages_of(path) == []
    assert (reports / "2026-03-02.html").read_text() == "a unit's report"


@pytest.mark.parametrize("name", ["a/b", "a\\b", "..", "", "x" * 300])
def test_batch_page_names_are_safe_and_apart(name):
    page = fleet.batch_page_name(name, 1)
    assert (
        "/" not in page and "\\" not in page and page.startswith("index-batch-") and page.endswith("-1.html")
    )
    assert len(page) < 80
    assert fleet.batch_page_name(name + "!", 1) != page


def test_a_days_manifest_splits_into_shards_that_keep_batches_and_devices_whole(tmp_path, monkeypatch):
    from gyrocal.fleet.manifest import read_manifest
    from gyrocal.run.cli import main

    (tmp_path / "logs").mkdir()
    lines = ["device\tbatch\tsession\tprotocol\tpath"]
    for batch, devices in (("B1", 3), ("B2", 7), ("B3", 2)):
        for d in range(devices):
            for session in ("2026-03-02", "2026-03-03"):
                lines.append(
                    f"{batch}D{d}\t{batch}\t{session}\tturntable\tlogs/{batch}D{d}-{session}.parquet"
                )
    (tmp_path / "day.tsv").write_text("\n".join(lines) + "\n")
    monkeypatch.chdir(tmp_path)  # the manifest named relative to where the command runs
    assert main(["shard", "--manifest", "day.tsv", "--size", "8", "-o", "shards"]) == 0
    day = read_manifest(tmp_path / "day.tsv")
    shards = [read_manifest(p) for p in sorted((tmp_path / "shards").glob("shard-*.tsv"))]
    # every row once, in order, with its log where the manifest put it
    key = ("device", "batch", "session", "protocol", "log")
    assert [tuple(r[c] for c in key) for s in shards for r in s] == [tuple(r[c] for c in key) for r in day]
    assert all(len(s) <= 8 for s in shards)
    # B1 (6 rows) and B3 (4) whole; B2 (14 rows > 8) split between devices, never within one
    where = {}
    for k, s in enumerate(shards):
        for r in s:
            where.setdefault(r["batch"], set()).add(k)
            where.setdefault(r["device"], set()).add(k)
    assert len(where["B1"]) == len(where["B3"]) == 1 and len(where["B2"]) == 2
    assert all(len(where[f"B2D{d}"]) == 1 for d in range(7))
