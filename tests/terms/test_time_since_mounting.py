"""``t_mount``: time since the unit was last mounted, from the handling segmentation
rejects, read by terms as a series signal in the fit and infinite in apply."""

from __future__ import annotations

import numpy as np

from gyrocal.fit.model import Model
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings
from gyrocal.simulate import TurntableProtocol, simulate_unit
from gyrocal.terms import make_term

RELAX = {
    "name": "expression",
    "label": "relax",
    "formula": "exp(-t_mount / tau)",
    "parameters": {"tau": 60.0},
}


def test_each_hold_is_mounted_at_the_end_of_the_handling_before_it(tmp_path):
    """Three mounts per point: every hold's ``mounted_at`` is the end of the last segment
    rejected as handling before it, or the log's first sample before any; the holds of one
    stretch on a mount share it."""
    log = tmp_path / "u.parquet"
    simulate_unit(log, rig=TurntableProtocol.quick(), rng=np.random.default_rng(5))
    seg = segment_log(log, Settings())
    obs, segments = seg.observations, seg.segments
    handled = np.sort(segments.loc[segments["reason"] == "handling_motion", "t_end"].to_numpy(float))
    assert handled.size >= 2
    for start, mounted in zip(obs["t_start"], obs["mounted_at"], strict=True):
        before = handled[handled <= start]
        assert mounted == (before[-1] if before.size else mounted)
        assert mounted <= start
    assert np.unique(obs["mounted_at"]).size >= handled.size  # one per mounting at least


def test_each_hold_knows_when_its_log_last_resumed_after_a_gap(tmp_path):
    """A log with ten minutes cut out of its middle (the unit off, or the logger paused):
    the holds after the cut resumed at its end, those before at the log's first sample; a log
    without a gap resumes nowhere."""
    import pandas as pd

    log = tmp_path / "u.parquet"
    simulate_unit(log, rig=TurntableProtocol.quick(), rng=np.random.default_rng(5))
    whole = segment_log(log, Settings()).observations
    assert np.unique(whole["resumed_at"]).size == 1
    frame = pd.read_parquet(log)
    t = frame["t"].to_numpy(float)
    mid = 0.5 * (t[0] + t[-1])
    cut = tmp_path / "cut.parquet"
    frame[(t < mid) | (t > mid + 600.0)].to_parquet(cut, index=False)
    obs = segment_log(cut, Settings()).observations
    after = obs["t_start"].to_numpy(float) > mid
    assert after.any() and (~after).any()
    resumed = obs["resumed_at"].to_numpy(float)
    assert np.all(resumed[~after] == t[0])
    assert np.all((resumed[after] > mid + 599.0) & (resumed[after] <= obs["t_start"].to_numpy(float)[after]))


def test_a_relaxation_after_mounting_reads_the_holds_and_is_settled_in_apply(tmp_path):
    """At holds the term is the hold's mean of exp(-(t - mounted_at)/tau) over its samples;
    on samples without mountings (a stream in the field) it is zero: long since mounted."""
    log = tmp_path / "u.parquet"
    simulate_unit(log, rig=TurntableProtocol.quick(), rng=np.random.default_rng(5))
    obs = segment_log(log, Settings()).observations
    model = Model((make_term(RELAX),))
    design = model.design({**obs.to_dict("series"), "series": obs.attrs["series"]})
    column = next(iter(design.values()))
    start = obs["t_start"].to_numpy(float) - obs["mounted_at"].to_numpy(float)
    end = obs["t_end"].to_numpy(float) - obs["mounted_at"].to_numpy(float)
    # the mean of exp(-s/60) over [start, end]
    expected = 60.0 * (np.exp(-start / 60.0) - np.exp(-end / 60.0)) / (end - start)
    np.testing.assert_allclose(column, expected, rtol=2e-3, atol=1e-9)
    stream = {"t": np.linspace(0.0, 100.0, 5), "temp": np.full(5, 25.0)}
    samples = model.design(stream | {f"rate_{a}": np.zeros(5) for a in "xyz"})
    assert np.all(next(iter(samples.values())) == 0.0)
