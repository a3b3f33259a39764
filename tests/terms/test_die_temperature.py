"""The die's temperature (``die_temperature``): the temperature every temperature dependence
of the model is evaluated at, the logged one through a first-order lag, in the fit, in
``apply`` (a filter over the samples, batch by batch) and in the calibration file."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gyrocal.calibration.apply import apply_calibration
from gyrocal.calibration.file import Calibration, load_calibration, save_calibration
from gyrocal.fit.model import Model
from gyrocal.fit.thermal import ConstantCoefficients
from gyrocal.io.errors import MissingInputError
from gyrocal.terms import make_term
from gyrocal.terms.signals import LagFilter, Series, first_order_lag


@given(st.integers(0, 2**31 - 1), st.lists(st.integers(1, 400), min_size=1, max_size=6))
def test_a_lag_given_in_pieces_is_the_lag_of_the_whole(seed, cuts):
    rng = np.random.default_rng(seed)
    n = 500
    t = np.cumsum(rng.uniform(0.01, 3.0, n))
    t[200:] += 5000.0  # a gap of many time constants
    x = np.cumsum(rng.standard_normal(n))
    whole = first_order_lag(t, x, 37.0)
    lag = LagFilter(37.0)
    edges = sorted({0, n, *(c % n for c in cuts)})
    pieces = np.concatenate([lag(t[a:b], x[a:b]) for a, b in zip(edges[:-1], edges[1:], strict=False)])
    np.testing.assert_allclose(pieces, whole, rtol=1e-11, atol=1e-11)


def test_samples_the_filter_cannot_read_are_skipped_and_read_nan():
    t = np.arange(10.0)
    x = np.linspace(20.0, 29.0, 10)
    holed = x.copy()
    holed[4] = np.nan
    out = LagFilter(5.0)(t, holed)
    assert np.isnan(out[4])
    keep = np.arange(10) != 4
    np.testing.assert_allclose(out[keep], first_order_lag(t[keep], x[keep], 5.0), rtol=1e-13)


def ramp_holds(rate_c_per_s=1 / 60, tau=600.0, t0=20.0):
    """Holds along a temperature ramp from equilibrium: the record (1 s points), and each
    hold's exact mean die temperature, ``T0 + r t − r τ (1 − e^(−t/τ))`` averaged over it."""
    t = np.arange(0.0, 7200.0 + 1.0, 1.0)
    series = Series(t, t0 + rate_c_per_s * t, 0.0, 60.0, np.ones(t.size))
    a = np.arange(100.0, 7000.0, 300.0)
    b = a + 20.0
    r = rate_c_per_s
    exact = t0 + r * (a + b) / 2 - r * tau + r * tau**2 * (np.exp(-a / tau) - np.exp(-b / tau)) / (b - a)
    data = {
        "t_start": a,
        "t_end": b,
        "temp": t0 + r * (a + b) / 2,
        "series": series,
        "rate_x": np.zeros(a.size),
        "rate_y": np.zeros(a.size),
        "rate_z": np.zeros(a.size),
    }
    return data, exact


def test_each_hold_reads_the_mean_of_the_lagged_record():
    data, exact = ramp_holds()
    die = make_term("die_temperature(tau=600.0)")
    lagged = die.transform_inputs(data)
    # Exact but for the trapezoid rule between the record's 1 s points: below
    # r / (12 τ) · (1 s)² ≈ 2e-6 °C.
    np.testing.assert_allclose(lagged["temp"], exact, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(lagged["temp_logged"], data["temp"])
    again = die.transform_inputs(lagged)  # from the logged temperature again
    np.testing.assert_array_equal(again["temp"], lagged["temp"])
    # Teeth: the lag on this ramp is r τ = 10 °C once settled.
    assert np.max(np.abs(lagged["temp"] - data["temp"])) > 9.0


def test_a_temperature_term_is_evaluated_at_the_die():
    data, exact = ramp_holds()
    model = Model.from_spec(["bias", "bias_temp_poly(degree=2)", "die_temperature(tau=600.0)"])
    design = model.design(model.transform_inputs(data))
    # The die temperatures within 1e-5 °C (above): their squares within 2·50·1e-5.
    np.testing.assert_allclose(design["bias_temp_poly.x.c2"], (exact - 25.0) ** 2, rtol=0, atol=1e-3)
    plain = Model.from_spec(["bias", "bias_temp_poly(degree=2)"])
    assert (
        np.max(
            np.abs(
                plain.design(plain.transform_inputs(data))["bias_temp_poly.x.c1"]
                - design["bias_temp_poly.x.c1"]
            )
        )
        > 9.0
    )


def test_holds_without_the_record_are_refused_by_name():
    data, _ = ramp_holds()
    data.pop("series")
    with pytest.raises(MissingInputError, match="temperature record"):
        make_term("die_temperature").transform_inputs(data)


def die_calibration(tau=300.0):
    """A continuous calibration whose bias is steep in the die's temperature."""
    model = Model.from_spec(["bias", "scale", "bias_temp_poly(degree=2)", f"die_temperature(tau={tau})"])
    values = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.005, 0.02, 1e-4, -0.03, -2e-4, 0.015, 3e-4])
    names = tuple(model.names)
    assert len(names) == len(values)
    grid = ConstantCoefficients(
        np.array([0.0, 20.0, 40.0]), names, values, np.full(len(values), 1e-5), fitted_span=(-5.0, 45.0)
    )
    return Calibration(model, grid, meta={"device": "D", "batch": "B", "session": "s", "protocol": "sweep"})


def ramp_log(path, n=30_000):
    """A log whose temperature ramps up and down at 3 °C/min, 10 Hz."""
    t = np.arange(n) * 0.1
    temp = 20.0 + 15.0 * np.sin(2 * np.pi * t / 1800.0)
    gyro = np.column_stack([np.full(n, 10.0), np.full(n, -5.0), np.full(n, 2.0)])
    pq.write_table(
        pa.table(
            {
                "t": t,
                "gyro_x": gyro[:, 0],
                "gyro_y": gyro[:, 1],
                "gyro_z": gyro[:, 2],
                "temp": temp,
                "ref_rate": np.zeros(n),
            }
        ),
        path,
    )
    return t, temp, gyro


def test_apply_runs_the_lag_over_the_samples_across_batches(tmp_path, monkeypatch):
    import gyrocal.calibration.apply as apply_module

    cal_path = tmp_path / "cal.json"
    save_calibration(die_calibration(), cal_path)
    cal = load_calibration(cal_path)
    assert cal.model.terms[-1].spec_string() == "die_temperature(tau=300.0)"
    t, temp, gyro = ramp_log(tmp_path / "log.parquet")
    monkeypatch.setattr(apply_module, "BATCH_ROWS", 7_001)  # several batches, uneven
    apply_calibration(cal, tmp_path / "log.parquet", tmp_path / "out.parquet")
    out = pq.read_table(tmp_path / "out.parquet")
    got = np.column_stack([out.column(c).to_numpy() for c in ("gyro_x", "gyro_y", "gyro_z")])
    # The whole record at once, from its start (what compensate does given samples).
    whole = cal.compensate(gyro, {"t": t, "temp": temp}, warn=False)
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-9)
    # Teeth: the logged temperature instead of the die's errs by up to b1·(r τ) ≈ 0.2 deg/s.
    at_logged = cal.compensate(gyro, {"t": t, "temp": temp, "temp_logged": temp}, warn=False)
    assert np.max(np.abs(got - at_logged)) > 0.05


def test_the_lag_comes_back_from_the_file():
    cal = die_calibration(tau=123.5)
    again = Calibration.from_dict(cal.to_dict())
    assert [t.spec_string() for t in again.model.terms] == [t.spec_string() for t in cal.model.terms]
    assert again.model.sample_transforms() and again.grid.span == (-5.0, 45.0)


def test_a_fit_finds_the_die_lag_on_holds_of_a_sweep():
    """Holds along a ramp up and down whose bias follows the die's temperature with a
    quadratic: the profile finds τ, and the calibration reproduces the holds."""
    from gyrocal.fit.thermal import fit_model

    tau, r = 420.0, 1 / 60
    t = np.arange(0.0, 14400.0 + 1.0, 1.0)
    temp = np.where(t < 7200.0, 0.0 + r * t, 0.0 + r * (14400.0 - t))
    series = Series(t, temp, 0.0, 60.0, np.ones(t.size))
    die = first_order_lag(t, temp, tau)
    a = np.arange(200.0, 14100.0, 60.0)
    b = a + 20.0
    holds = {
        "t_start": a,
        "t_end": b,
        "series": series,
        "point": np.floor(np.interp(a, t, temp) / 10.0),
        **{f"rate_{x}": np.zeros(a.size) for x in "xyz"},
    }
    inside = (t[None, :] >= a[:, None]) & (t[None, :] <= b[:, None])
    die_mean = (inside * die).sum(1) / inside.sum(1)
    rng = np.random.default_rng(3)
    bias = np.column_stack([0.2 + 0.02 * (die_mean - 25) + 3e-4 * (die_mean - 25) ** 2] * 3)
    floor = 0.002
    holds.update(
        temp=(inside * temp).sum(1) / inside.sum(1),
        **{f"gyro_{x}": bias[:, i] + floor * rng.standard_normal(a.size) for i, x in enumerate("xyz")},
        **{f"std_{x}": np.full(a.size, floor * np.sqrt(20.0)) for x in "xyz"},
        n=np.full(a.size, 20.0),
    )
    model = Model.from_spec(["bias", "bias_temp_poly(degree=2)", "die_temperature"])
    fitted = fit_model(model, holds, kind="continuous")
    found = fitted.profiled[0]
    assert found["term"] == "die_temperature" and found["identified"]
    assert abs(found["value"] - tau) < max(5 * found["stderr"], 0.02 * tau), found
    chi2 = sum(fitted.fit.chi2.values()) / sum(fitted.fit.dof.values())
    assert chi2 < 1.5  # the floor, not the lag, is left
