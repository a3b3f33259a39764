"""The missing-effect diagnosis on the smallest zoo of ``benchmarks/diagnosis.py``: units
from the independent generator (``benchmarks/zoo``), scored as the benchmark scores them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from diagnosis import SMALLEST, run_case  # noqa: E402

# What the generator's author calls each effect's floor multiple after the right fix must
# reach: the target for an identifiable effect.
NEXT_SESSION_LIMIT = 1.2


@pytest.mark.parametrize("case", SMALLEST, ids=lambda c: f"{c[0]}-{c[1]}")
def test_the_smallest_zoo_is_diagnosed_without_a_wrong_name(case, tmp_path):
    row = run_case(case, 1, str(tmp_path))
    expected = case[3]
    if expected == "none":
        assert row["outcome"] == "quiet", row["verdict"]
        assert row["best"] is None
    elif expected == "outside":
        assert row["best"] is None, row["verdict"]       # never a wrong name
        assert row["outcome"] in ("outside", "partial")
    else:
        assert row["outcome"] == "named right", row["verdict"]
        assert row["next_after"] <= NEXT_SESSION_LIMIT
        assert row["next_before"] > 2 * NEXT_SESSION_LIMIT  # the effect was there to find


def test_where_it_fails_is_measured_against_what_does_not_contain_it(tmp_path):
    """A warm-up on three mounts: the excess is drift within each temperature point (time,
    not temperature); the mount and the rotating axis, which this protocol cannot tell
    apart, are one row; and a covariate is not credited with another's excess."""
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.config import Settings
    from gyrocal.diagnose import diagnose
    from gyrocal.pipeline import segment_log

    log = tmp_path / "warmup.parquet"
    write_session(make_unit(effect="warmup", protocol="turntable3", noise="white", seed=2), log,
                  session=0, seed=7, rate_hz=25.0)
    diag = diagnose(Settings(), segment_log(log, Settings()).observations)
    rows = diag.covariates
    assert rows[0]["covariate"] == "time within a temperature point" and rows[0]["p_value"] < 1e-6
    assert any(r.get("confounded") == ["mount", "rotating axis"] for r in rows)
    rate_rows = [r for r in rows if r["covariate"] in ("|rate|", "direction", "reference rate")]
    assert rate_rows and all(r["within"] == "rotating axis" for r in rate_rows)
    # Before, shares were taken within the rotating axis, which on three mounts is the
    # mount: every covariate got the mount's share (99.9 % each in the report).
    assert sum((r["share_of_excess"] or 0) > 0.5 for r in rows) <= len(rows) // 3


def test_on_coloured_noise_the_verdict_says_the_excess_may_be_unresolved_wander(tmp_path):
    """A complete unit with Gauss-Markov bias wander of 200-860 s correlation time: a few
    minutes of static data cannot resolve it, and the verdict says so with the test it ran."""
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.config import Settings
    from gyrocal.diagnose import diagnose
    from gyrocal.pipeline import segment_log

    log = tmp_path / "coloured.parquet"
    write_session(make_unit(effect="none", protocol="turntable3", noise="coloured", seed=1), log,
                  session=0, seed=1000, rate_hz=25.0)
    diag = diagnose(Settings(), segment_log(log, Settings()).observations)
    assert diag.best is None
    if not diag.explains:
        assert diag.within_noise is not None and diag.within_noise["explains"]
        assert "the excess may be noise" in diag.verdict
