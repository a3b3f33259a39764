"""The temperature curvature a point left out of three misses (gyrocal.diagnosis.between.
drift_chord), on simulated units whose bias is a known polynomial in temperature: the
arithmetic of the chord, not a finding (the simulator and the formula agree by construction
of the physics, which is what is checked)."""

from __future__ import annotations

from gyrocal.diagnosis.evaluation import evaluate
from gyrocal.pipeline.chain import segment_log
from gyrocal.pipeline.config import Settings
from gyrocal.simulate.unit import GyroUnit

from ..conftest import make_log

THREE = (0.0, 20.0, 40.0)  # the middle point left out is read by the line through the ends
CURVATURE = 2e-4  # deg/s/°C²: 0.08 deg/s between the middle point and the chord of the ends


def _summary(tmp_path, name: str, curvature: float, temperatures=THREE) -> dict:
    unit = GyroUnit(bias_poly=((0.1, 2e-3, curvature, 0.0),) * 3, t_ref=20.0)
    log = make_log(tmp_path, name, unit=unit, temperatures=temperatures)
    settings = Settings()
    return evaluate(settings, segment_log(log, settings).observations, name).summary


def test_a_bias_curving_with_temperature_is_the_chord_three_points_leave(tmp_path):
    """B(T) = c·(T − 20)² on points at 0, 20 and 40 °C: leaving the middle point out, the
    line through the ends misses it by c·20² = 0.08 deg/s on every output, which is what the
    held-out error is; the chord (the calibration interpolated from the ends less the
    calibration from all three, its coefficients' noise taken out) finds it within the
    held-out figure's noise bar, and what a correct model leaves counts it."""
    s = _summary(tmp_path, "curved", CURVATURE)
    chord, noise = s["drift_chord_rms"], s["noise_floor"]
    assert s["validation_rms"] > 20 * noise, s
    assert abs(chord - CURVATURE * 20.0**2) <= 3 * noise, s
    assert s["validation_rms"] <= s["expected_rms"] * 1.2, s


def test_a_bias_linear_in_temperature_leaves_no_chord_beyond_its_noise(tmp_path):
    """A bias linear in temperature is interpolated exactly by the ends: the chord is the
    coefficients' noise alone, taken out, and leaves the bar within its noise of what it was
    (the held-out error's own uncertainty); with four points nothing is added at all."""
    s = _summary(tmp_path, "linear", 0.0)
    assert s["drift_chord_rms"] <= 2 * s["noise_floor"], s
    four = _summary(tmp_path, "four", CURVATURE, (0.0, 13.0, 27.0, 40.0))
    assert "drift_chord_rms" not in four, four
