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
