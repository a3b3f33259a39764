"""Seed papers' tables: seed 000 regenerated beside its published figures, the renderer,
and the `gyrocal paper` command (quick regenerations: hold means drawn directly)."""

from __future__ import annotations

import argparse
import csv
import io
import sys

import numpy as np
import pytest

from gyrocal.io.errors import InputError
from gyrocal.paper import SEEDS, add_parser, regenerate, seed000
from gyrocal.paper.render import render
from gyrocal.paper.table import PaperRow, PaperTable
from gyrocal.simulate import SEED000_RATES, GyroUnit

AXES = "XYZ"
PAIRS = [(r, o) for r in AXES for o in AXES]


@pytest.fixture(scope="module")
def tables():
    return {t.name: t for t in seed000.tables(seed=0, quick=True)}


def by_label(table: PaperTable) -> dict[str, PaperRow]:
    return {r.label: r for r in table.rows}


def test_every_figure_the_paper_prints_stands_beside_its_regeneration(tables):
    assert set(tables) == {"Table 3", "Table 4", "Eq. 23"}
    t3, t4, eq23 = (by_label(tables[n]) for n in ("Table 3", "Table 4", "Eq. 23"))
    printed = {
        "Table 3": [
            f"{r} rotates / {o} axis / {s}, {m}"
            for r, o in PAIRS
            for s in ("Mean", "RMS")
            for m in ("uncompensated", "proposed")
        ],
        "Table 4": [
            f"{r} rotates / {o} axis / {s}"
            for r, o in PAIRS
            for s in (
                "RMS, uncompensated",
                "RMS, traditional",
                "RMS, proposed",
                "reduction vs uncompensated",
                "reduction vs traditional",
            )
        ],
        "Eq. 23": [
            "K_xx",
            "K_yy",
            "K_zz",
            "K_yx",
            "K_zx",
            "K_xy",
            "K_zy",
            "K_xz",
            "K_yz",
            "B_x",
            "B_y",
            "B_z",
        ],
    }
    for name, labels in printed.items():
        rows = by_label(tables[name])
        assert all(rows[label].published is not None for label in labels), name
        # Only the added columns (noise floors) lack a published figure.
        assert {r.label for r in tables[name].rows if r.published is not None} == set(labels)
        assert all(np.isfinite(r.regenerated) for r in tables[name].rows)
    # Spot checks against the paper as printed.
    assert t3["X rotates / Y axis / RMS, uncompensated"].published == 4.0177
    assert t3["Z rotates / X axis / Mean, proposed"].published == 1.260e-4
    assert t4["Y rotates / Y axis / reduction vs traditional"].published == 25.64
    assert t4["Z rotates / Z axis / RMS, traditional"].published == -0.0060
    assert eq23["K_zy"].published == 5.2027e-4 and eq23["B_y"].published == -0.0435


def test_the_proposed_method_beats_uncompensated_wherever_the_paper_finds_it(tables):
    for name in ("Table 3", "Table 4"):
        rows = by_label(tables[name])
        for r, o in PAIRS:
            proposed = rows[f"{r} rotates / {o} axis / RMS, proposed"]
            uncompensated = rows[f"{r} rotates / {o} axis / RMS, uncompensated"]
            # Table 4's Z-rotates figures are signed means: compare magnitudes, as its percentages do.
            if abs(proposed.published) < abs(uncompensated.published):
                assert proposed.regenerated < uncompensated.regenerated, (name, r, o)


def test_the_proposed_method_leaves_the_noise(tables):
    t3, t4 = by_label(tables["Table 3"]), by_label(tables["Table 4"])
    for r, o in PAIRS:
        where = f"{r} rotates / {o} axis"
        # Hold means: 168 leave-temperature-out holds per pair, so the RMS of pure noise
        # scatters by 1/sqrt(2 * 168) = 5.5 %; the calibration's own uncertainty adds a few %.
        np.testing.assert_allclose(
            t3[f"{where} / RMS, proposed"].regenerated,
            t3[f"{where} / noise floor of hold means"].regenerated,
            rtol=0.25,
        )
        # Samples: the hold-mean error (~6e-4 deg/s) is negligible beside 0.05 deg/s of noise.
        np.testing.assert_allclose(
            t4[f"{where} / RMS, proposed"].regenerated,
            t4[f"{where} / per-sample noise"].regenerated,
            rtol=0.01,
        )


def test_the_traditional_calibration_misses_the_scale_change_since_its_temperature(tables):
    """On the rotating axis the single-temperature calibration leaves the unit's scale-factor
    and bias change between its point and the 25 °C session, in quadrature with the noise."""
    setup = seed000.regeneration(0, True).setup
    unit = GyroUnit.seed000()
    temps = [setup["test_temp"], setup["reference_temp"]]
    dK, dB = np.subtract(*unit.K(temps)), np.subtract(*unit.B(temps))
    mean_rate2 = np.mean(np.square((0.0,) + SEED000_RATES * 2))
    t4 = by_label(tables["Table 4"])
    for i, a in enumerate(AXES):
        where = f"{a} rotates / {a} axis"
        noise = t4[f"{where} / per-sample noise"].regenerated
        expected = np.sqrt(noise**2 + dK[i, i] ** 2 * mean_rate2 + dB[i] ** 2)
        # The 20 °C point's own fit is known to about 1 ppm in scale: far below the step.
        np.testing.assert_allclose(t4[f"{where} / RMS, traditional"].regenerated, expected, rtol=0.01)
        assert t4[f"{where} / reduction vs traditional"].regenerated > 5.0


def test_the_calibration_interpolated_to_25_C_recovers_the_simulated_units_truth(tables):
    """A recovery test, not a test of the paper: the simulated unit is built from Eq 23 (its K
    and B at a die temperature of 25 °C), and the paper's own data, from which gyrocal could
    calibrate its unit, are not published. The Eq. 23 table's published column is therefore
    also the truth this compares with."""
    r = seed000.regeneration(0, True)
    unit = GyroUnit.seed000()
    K, B = unit.K(seed000.TEST_TEMPERATURE), unit.B(seed000.TEST_TEMPERATURE)
    pick = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]  # Eq 23's order
    truth = np.array([*(K[i, j] for i, j in pick), *B])
    se = np.array([*(r.K25_se[i, j] for i, j in pick), *r.B25_se])
    regenerated = np.array([row.regenerated for row in tables["Eq. 23"].rows])
    published = np.array([row.published for row in tables["Eq. 23"].rows])
    # The unit keeps K as scale factors times (I + misalignment): Eq 23 back to rounding.
    np.testing.assert_allclose(truth, published, rtol=1e-15)
    assert np.all(se > 0)
    # 12 estimates: one beyond 4.5 standard errors has a chance of 12 x 7e-6 = 8e-5. The
    # three-point interpolation (12, 22, 32 °C) of the cubic bias to 25 °C misses by at most
    # 4e-8 x 13 x 3 x 7 = 1.1e-5 deg/s, a sixth of B's standard error.
    np.testing.assert_array_less(np.abs(regenerated - truth), 4.5 * se)


def run_cli(*argv):
    parser = argparse.ArgumentParser(prog="gyrocal")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


def test_the_command_writes_the_three_files_byte_identically_on_rerun(tmp_path, capsys):
    for name in ("a", "b"):
        seed000.regeneration.cache_clear()  # each run simulates afresh
        assert run_cli("paper", "--out", tmp_path / name, "--only", "000", "--quick") == 0
    out = capsys.readouterr().out
    assert "seed 000: 3 tables, 1 figures" in out
    files = ["tables.md", "tables.csv", "index.html", "figures/000-fig-9-rms-at-25c.svg"]
    for f in files:
        a, b = ((tmp_path / n / f).read_bytes() for n in ("a", "b"))
        assert a == b, f
        assert str(tmp_path).encode() not in a, f  # no absolute paths
    html = (tmp_path / "a" / "index.html").read_text()
    assert html.count("<svg") == 1 and 'id="000-table-4"' in html
    assert "<link" not in html and "<script" not in html and 'src="http' not in html  # self-contained
    md = (tmp_path / "a" / "tables.md").read_text()
    assert "| X rotates / Y axis / RMS, uncompensated | 4.0177 |" in md
    rows = list(csv.DictReader(io.StringIO((tmp_path / "a" / "tables.csv").read_text())))
    assert len(rows) == 45 + 54 + 12
    row = next(
        r for r in rows if r["label"] == "X rotates / X axis / RMS, proposed" and r["table"] == "Table 4"
    )
    assert row["seed"] == "000" and row["published"] == "0.0931" and row["unit"] == "deg/s"
    np.testing.assert_allclose(float(row["ratio"]), float(row["regenerated"]) / 0.0931, rtol=1e-5)


def test_unknown_seeds_are_refused():
    with pytest.raises(SystemExit) as exc:
        run_cli("paper", "--out", "x", "--only", "000,002")
    assert exc.value.code == 2
    assert SEEDS == ("000", "001", "003")


def test_a_seed_without_its_module_is_skipped_with_a_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "gyrocal.paper.seed001", None)  # import fails: not there
    lines = []
    paths = regenerate(tmp_path, only=("001",), quick=True, say=lines.append)
    assert [p.name for p in paths] == ["tables.md", "tables.csv", "index.html"]
    assert lines == ["gyrocal paper: seed 001 skipped: module gyrocal.paper.seed001 is not available"]
    assert "Seed 001: not regenerated" in (tmp_path / "tables.md").read_text()
    assert "Seed 001: not regenerated" in (tmp_path / "index.html").read_text()


def test_every_string_is_escaped(tmp_path):
    table = PaperTable(
        "000",
        "Table <X>",
        "a <i>title</i>",
        (PaperRow("a <b>label</b> | pipe", 1.5, 3.0, "<u>"),),
        ("set-up <script>alert(1)</script> & more",),
    )
    render([table], tmp_path)
    html = (tmp_path / "index.html").read_text()
    assert "<script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "<b>label" not in html and "&lt;b&gt;label" in html
    md = (tmp_path / "tables.md").read_text()
    assert "<script>" not in md and "a &lt;b&gt;label&lt;/b&gt; \\| pipe | 3 | 1.5 | 0.5 |" in md


def test_render_refuses_what_it_cannot_show(tmp_path):
    table = PaperTable("000", "Table 3", "t", (PaperRow("a", 1.0),))
    with pytest.raises(InputError, match="found twice: 000-table-3"):
        render([table, table], tmp_path)
    with pytest.raises(InputError, match="expected PaperTable"):
        render([{"seed": "000"}], tmp_path)
    text = tmp_path / "figure.txt"
    text.write_text("not a picture")
    with pytest.raises(InputError, match="expected an .svg or .png file"):
        render([table], tmp_path, figures={"000": [text]})
