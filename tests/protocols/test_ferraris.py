"""The hand-rotation (Ferraris) protocol: segmentation from the data and from an annotation,
the calibration against the simulator's truth, refusals, and the real session of
data/real/imucal-ferraris against imucal's own calibration of it."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from gyrocal.io.errors import ConfigError, SegmentationError
from gyrocal.io.log import ACCEL, REQUIRED, read_log
from gyrocal.pipeline.chain import run, segment_log
from gyrocal.pipeline.config import Settings
from gyrocal.protocols import registry
from gyrocal.protocols.ferraris.segment import segment_ferraris
from gyrocal.simulate import GyroUnit, simulate_unit
from gyrocal.simulate.ferraris import FerrarisProtocol

from .conftest import needs

REAL = Path(__file__).resolve().parents[2] / "data" / "real" / "imucal-ferraris"
RATE = 102.4  # the real session's sample rate (its README)


def ferraris_log(tmp_path, *, seed=1, name="F001", unit=None, **rig):
    path = tmp_path / f"{name}.parquet"
    truth = simulate_unit(
        path,
        protocol="ferraris",
        rig=FerrarisProtocol(**rig),
        unit=unit or GyroUnit.random(np.random.default_rng(seed + 100)),
        rng=np.random.default_rng(seed),
        device=name,
        seed=seed,
    )
    return path, truth


def settings_with(**options) -> Settings:
    return Settings.from_dict({"protocols": {"ferraris": {"options": options}}}).for_protocol("ferraris")


def K_stderr(cal) -> np.ndarray:
    """The standard errors of K's entries, laid out as K."""
    se = dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))
    return np.array(
        [
            [se["scale.x"], se["misalignment.x.y"], se["misalignment.x.z"]],
            [se["misalignment.y.x"], se["scale.y"], se["misalignment.y.z"]],
            [se["misalignment.z.x"], se["misalignment.z.y"], se["scale.z"]],
        ]
    )


def expected_K(truth) -> np.ndarray:
    """What a turn can show of K: each column is K times the turn's true rotation axis and
    angle over the nominal full turn (the unit's tilt lands in the cross-axis terms)."""
    unit = GyroUnit.from_dict(truth["unit"])
    K = unit.K(25.0)
    cols = [K @ np.asarray(t["rotation_axis"]) * abs(t["true_angle_deg"]) / 360.0 for t in truth["turns"]]
    return np.column_stack(cols)


@pytest.mark.parametrize(
    "seed,rig",
    [(1, {}), (2, {"steps": 4}), (3, {"sections": True}), (4, {"temperature": None, "sample_rate": 200.0})],
)
def test_recovers_what_the_turns_show_within_the_noise(tmp_path, seed, rig):
    """With the hand's assumed errors set to zero the standard errors are the noise's alone:
    K and B must then match what the simulated turns and faces show within 4 of them."""
    path, truth = ferraris_log(tmp_path, seed=seed, **rig)
    result = run(
        path, settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0), protocol="ferraris"
    )
    cal = result.calibration
    K, B = cal.matrices()[0][0], cal.matrices()[1][0]
    se = dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))
    unit = GyroUnit.from_dict(truth["unit"])
    want = expected_K(truth)
    K_se = K_stderr(cal)
    assert np.all(np.abs(K - want) < 4 * K_se), (K - want) / K_se
    B_se = np.array([se[f"bias.{a}"] for a in "xyz"])
    assert np.all(np.abs(B - unit.B(25.0)) < 4 * B_se), (B - unit.B(25.0)) / B_se
    obs = result.segmentation.observations
    assert sorted(obs["section"]) == sorted(
        ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a", "x_rot", "y_rot", "z_rot"]
    )
    assert result.segmentation.info["phases_from"] == ("annotation" if rig.get("sections") else "data")
    codes = [w["code"] for w in cal.extra["warnings"]]
    assert ("temperature_not_logged" in codes) == (rig.get("temperature", 25.0) is None)
    assert "single_temperature" not in codes


@pytest.mark.parametrize("seed", [5, 16, 17])
def test_hand_errors_are_inside_the_stated_uncertainty(tmp_path, seed):
    """With the default assumptions (a 1° guide, a unit flat to 0.5°) and a hand that errs
    as much (rms), the calibration covers the true scale within 3 standard errors."""
    path, truth = ferraris_log(tmp_path, seed=seed, guide_error_deg=1.0, tilt_deg=0.5)
    cal = run(path, Settings().for_protocol("ferraris"), protocol="ferraris").calibration
    K = cal.matrices()[0][0]
    unit = GyroUnit.from_dict(truth["unit"])
    se = dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))
    scale_se = np.array([se[f"scale.{a}"] for a in "xyz"])
    assert np.all(np.abs(np.diag(K) - np.diag(unit.K(25.0))) < 3 * scale_se)


def test_faces_found_by_gravity_match_the_truth(tmp_path):
    path, truth = ferraris_log(tmp_path, seed=6)
    seg = segment_log(path, Settings().for_protocol("ferraris"), "ferraris")
    faces = seg.observations.set_index("section")
    for f in truth["faces"]:
        row = faces.loc[f["face"]]
        assert f["t_start"] <= row["t_start"] and row["t_end"] <= f["t_end"] + 1e-9
    for t in truth["turns"]:
        row = faces.loc[f"{t['axis']}_rot"]
        assert np.sign(row["angle"]) == np.sign(t["true_angle_deg"])
        # the found turn spans the true motion (rests on either side may be included)
        assert row["t_start"] <= t["t_start"] + 0.2 and row["t_end"] >= t["t_end"] - 0.2


def _drop_rows(path, keep) -> Path:
    table = pq.read_table(path)
    out = path.with_name(path.stem + "_cut.parquet")
    pq.write_table(table.filter(pa.array(keep(table.column("t").to_numpy()))), out)
    return out


def test_missing_face_and_missing_turn_are_named(tmp_path):
    path, truth = ferraris_log(tmp_path, seed=7)
    face = next(f for f in truth["faces"] if f["face"] == "y_a")
    cut = _drop_rows(path, lambda t: (t < face["t_start"] - 0.5) | (t > face["t_end"] + 0.5))
    with pytest.raises(SegmentationError, match=r"the -y face \(y down\)"):
        run(cut, Settings().for_protocol("ferraris"), protocol="ferraris")
    turn = next(t for t in truth["turns"] if t["axis"] == "z")
    cut = _drop_rows(path, lambda t: t < turn["t_start"])
    with pytest.raises(SegmentationError, match="a full turn about z"):
        run(cut, Settings().for_protocol("ferraris"), protocol="ferraris")


def test_half_turn_is_not_taken_for_a_full_one(tmp_path):
    """A turn cut at half its angle reads 180°: not used, said, and its axis reported missing."""
    path, truth = ferraris_log(tmp_path, seed=8, steps=2)
    turn = next(t for t in truth["turns"] if t["axis"] == "x")
    middle = 0.5 * (turn["t_start"] + turn["t_end"])
    cut = _drop_rows(path, lambda t: (t < middle - 0.2) | (t > turn["t_end"] + 1.0))
    with pytest.raises(SegmentationError, match="a full turn about x"):
        run(cut, Settings().for_protocol("ferraris"), protocol="ferraris")


def _exclusive_minimum_zero() -> list[str]:
    properties = registry.options_schema("ferraris")["properties"]
    return [name for name, p in properties.items() if p.get("exclusiveMinimum") == 0]


@pytest.mark.parametrize("option", _exclusive_minimum_zero())
def test_an_option_the_schema_keeps_above_0_refuses_0(tmp_path, option):
    """The segmenter holds its options to the config schema's bounds, however it is called:
    0 where the schema says exclusiveMinimum 0 is a one-line error naming the setting."""
    path, _ = ferraris_log(tmp_path, seed=11)
    without = registry.get("ferraris").without
    log = read_log(path, optional=ACCEL + without, required=tuple(c for c in REQUIRED if c not in without))
    with pytest.raises(ConfigError) as refused:
        segment_ferraris(log, {option: 0})
    assert str(refused.value) == f"protocols.ferraris.options.{option} must be more than 0, got 0"
    assert registry.option_defaults("ferraris")[option] > 0


def test_no_accelerometer_and_no_annotation_is_refused(tmp_path):
    path, _ = ferraris_log(tmp_path, seed=9, accel_columns=False)
    with pytest.raises(SegmentationError, match="needs accel_x, accel_y, accel_z"):
        run(path, Settings().for_protocol("ferraris"), protocol="ferraris")


def test_unknown_section_label_is_refused(tmp_path):
    path, _ = ferraris_log(tmp_path, seed=10, sections=True)
    table = pq.read_table(path)
    labels = table.column("section").to_pylist()
    labels[100] = "x_rotation"
    table = table.set_column(table.schema.get_field_index("section"), "section", pa.array(labels))
    pq.write_table(table, path)
    with pytest.raises(SegmentationError, match="'x_rotation'"):
        run(path, Settings().for_protocol("ferraris"), protocol="ferraris")


# -- the real session -------------------------------------------------------------------


def real_log(tmp_path, *, annotated: bool) -> Path:
    """The real session as a contract log (what ``gyrocal import`` with its map writes)."""
    from gyrocal.importer import import_log

    out = tmp_path / ("annotated.parquet" if annotated else "plain.parquet")
    mapping = yaml_map(tmp_path, annotated)
    import_log(REAL / "session.csv", out, mapping)
    return out


def yaml_map(tmp_path, annotated: bool) -> Path:
    text = (REAL / "import.yaml").read_text()
    if not annotated:
        text = "\n".join(line for line in text.splitlines() if not line.startswith("sections"))
    path = tmp_path / f"map_{annotated}.yaml"
    path.write_text(text.replace("sections.json", str(REAL / "sections.json")))
    return path


def imucal_calibration():
    from imucal import FerrarisCalibration, ferraris_regions_from_section_list

    data = pd.read_csv(REAL / "session.csv").set_index("n_samples")
    sections = pd.DataFrame(json.loads((REAL / "sections.json").read_text())).T
    regions = ferraris_regions_from_section_list(data, sections)
    return FerrarisCalibration().compute(
        regions, sampling_rate_hz=RATE, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
    )


HAS_IMUCAL = importlib.util.find_spec("imucal") is not None


@needs({"imucal": HAS_IMUCAL}, "pip install imucal, or make test")
def test_real_session_agrees_with_imucal(tmp_path):
    """The annotated real session calibrated by gyrocal against imucal's calibration of the
    same samples. Both read the same data, so their noise is shared: what differs is the
    method (imucal takes each turn's offset from its own face through the acceleration
    sensitivity). The bound is the noise alone, the standard errors with the hand's
    assumed errors at zero: the methods must agree within 3 of them on every term."""
    path = real_log(tmp_path, annotated=True)
    cal = run(
        path, settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0), protocol="ferraris"
    ).calibration
    K, B = cal.matrices()[0][0], cal.matrices()[1][0]
    se = dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))
    K_se = K_stderr(cal)
    B_se = np.array([se[f"bias.{a}"] for a in "xyz"])
    ref = imucal_calibration()
    K_ref = ref.K_g @ ref.R_g
    assert np.all(np.abs(K - K_ref) < 3 * K_se), (K - K_ref) / K_se
    assert np.all(np.abs(B - ref.b_g) < 3 * B_se), (B - ref.b_g) / B_se
    # the sensor is far from ideal: the comparison is not of two identity matrices
    assert abs(K[0, 0] - 1.0) > 10 * K_se[0, 0]


def test_real_session_phases_from_the_data_match_the_annotation(tmp_path):
    """Found from the data alone, the faces and turns give the calibration the person's
    annotation gives, within the noise-only standard errors (different samples, the same
    physics)."""
    s = settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0)
    found = run(real_log(tmp_path, annotated=False), s, protocol="ferraris")
    marked = run(real_log(tmp_path, annotated=True), s, protocol="ferraris")
    assert found.segmentation.info["phases_from"] == "data"
    a, b = found.calibration, marked.calibration
    se = np.hypot(a.grid.stderr[0], b.grid.stderr[0])
    assert np.all(np.abs(a.grid.values[0] - b.grid.values[0]) < 3 * se)
    turns = found.segmentation.observations.set_index("section")
    assert (turns.loc[["x_rot", "y_rot", "z_rot"], "angle"] == -360.0).all()  # clockwise, as imucal's


def imucal_terms(ref) -> dict[str, float]:
    """imucal's calibration as gyrocal's parameters (``w = K w_true + B``: K − I and B)."""
    K = ref.K_g @ ref.R_g
    out = {f"bias.{a}": float(ref.b_g[i]) for i, a in enumerate("xyz")}
    for i, a in enumerate("xyz"):
        for j, b in enumerate("xyz"):
            name = f"scale.{a}" if i == j else f"misalignment.{a}.{b}"
            out[name] = float(K[i, j] - (i == j))
    return out


def z_against_imucal(cal, ref) -> dict[str, float]:
    """Every term's difference from imucal's, in the calibration's standard errors."""
    want = imucal_terms(ref)
    return {
        name: (value - want[name]) / se
        for name, value, se in zip(cal.grid.names, cal.grid.values[0], cal.grid.stderr[0], strict=False)
    }


def cut_to_sections(path: Path, *, rows_as_time: bool) -> Path:
    """The real session as a recording trimmed to its annotated sections: the handling
    between them dropped, the sections joined in time order with no move between them.
    ``rows_as_time``: time counts the kept rows (no gap where a cut was), else it keeps the
    sample index (a gap at every cut)."""
    sections = json.loads((REAL / "sections.json").read_text())
    table = pq.read_table(path)
    keep = np.zeros(table.num_rows, bool)
    for span in sections.values():
        keep[span["start"] : span["end"]] = True
    table = table.filter(pa.array(keep))
    if rows_as_time:
        table = table.set_column(0, "t", pa.array(np.arange(table.num_rows) / RATE))
    out = path.with_name(f"cut_{rows_as_time}.parquet")
    pq.write_table(table, out)
    return out


@needs({"imucal": HAS_IMUCAL}, "pip install imucal, or make test")
@pytest.mark.parametrize("rows_as_time", [False, True])
def test_real_session_cut_to_its_sections_segments_from_the_data(tmp_path, rows_as_time):
    """A recording trimmed to its sections has no move between one face and the next: the
    six faces are one still stretch whose gravity turns by 90° or 180° from face to face.
    Found from the data alone, the sections are the person's (each turn to the sample) and
    the calibration agrees with imucal's within 3 noise-only standard errors on every term."""
    cut = cut_to_sections(real_log(tmp_path, annotated=False), rows_as_time=rows_as_time)
    result = run(cut, settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0), protocol="ferraris")
    info = result.segmentation.info
    assert info["phases_from"] == "data" and info["cuts"] == 8
    obs = result.segmentation.observations.set_index("section")
    sections = json.loads((REAL / "sections.json").read_text())
    start = {}  # each section's first row in the cut log
    at = 0
    for label, span in sorted(sections.items(), key=lambda kv: kv[1]["start"]):
        start[label], at = at, at + span["end"] - span["start"]
    t = pq.read_table(cut, columns=["t"]).column("t").to_numpy()
    for label in ("x_rot", "y_rot", "z_rot"):
        span = sections[label]
        assert obs.loc[label, "n"] == span["end"] - span["start"], label
        assert obs.loc[label, "t_start"] == t[start[label]]
        assert obs.loc[label, "angle"] == -360.0
    for label in ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a"):
        first = t[start[label]]
        last = t[start[label] + sections[label]["end"] - sections[label]["start"] - 1]
        assert first <= obs.loc[label, "t_start"] and obs.loc[label, "t_end"] <= last, label
        assert obs.loc[label, "n"] >= 0.9 * (sections[label]["end"] - sections[label]["start"]) - 25
    z = z_against_imucal(result.calibration, imucal_calibration())
    assert max(abs(v) for v in z.values()) < 3, z


# The map of the real session in imucal's labelled form: nothing but the map is needed.
LABELLED_MAP = """\
time: {column: samples, sample_rate: 102.4, sort: true}   # the rows come grouped by label
gyro: {x: gyr_x, y: gyr_y, z: gyr_z, unit: deg/s}
accel: {x: acc_x, y: acc_y, z: acc_z, unit: m/s^2}
sections: {column: part}
"""


def labelled_session(folder: Path, *, label: bool = True) -> Path:
    """The real session in imucal's labelled form, the one ``ferraris_regions_from_df``
    takes: a ``part`` column naming every row's section and the sample index as
    ``samples``, cut to the sections (the handling between them dropped), rows grouped by
    label in imucal's order (x_a before x_p). ``label=False``: the same file without its
    label column."""
    data = pd.read_csv(REAL / "session.csv").rename(columns={"n_samples": "samples"})
    sections = json.loads((REAL / "sections.json").read_text())
    parts = [
        data.iloc[span["start"] : span["end"]].assign(part=label_)
        for label_, span in sorted(sections.items())
    ]
    table = pd.concat(parts)[["part", "samples", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]]
    if not label:
        table = table.drop(columns="part")
    path = folder / ("labelled.csv" if label else "unlabelled.csv")
    table.to_csv(path, index=False)
    return path


def imported(tmp_path, source: Path, map_text: str) -> Path:
    """``gyrocal import SOURCE --map MAP`` as a user runs it."""
    from gyrocal.run import cli

    (tmp_path / "map.yaml").write_text(map_text)
    out = tmp_path / (source.stem + ".parquet")
    assert cli.main(["import", str(source), "--map", str(tmp_path / "map.yaml"), "-o", str(out)]) == 0
    return out


@needs({"imucal": HAS_IMUCAL}, "pip install imucal, or make test")
def test_imucal_labelled_session_imports_with_its_map_and_calibrates_as_imucal(tmp_path):
    """imucal's labelled form, its sections as a label column on every row and its rows
    grouped by label, imports from its own file with a map alone. Calibrated from that
    annotation, every term lies within 1 noise-only standard error of imucal's calibration
    of the same file (read by imucal's own ferraris_regions_from_df); the same file
    without its label column, segmented from the data alone, within 3."""
    from imucal import FerrarisCalibration, ferraris_regions_from_df

    source = labelled_session(tmp_path)
    frame = pd.read_csv(source).set_index("part")
    ref = FerrarisCalibration().compute(
        ferraris_regions_from_df(frame), sampling_rate_hz=RATE, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
    )
    noise_only = settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0)
    marked = run(imported(tmp_path, source, LABELLED_MAP), noise_only, protocol="ferraris")
    assert marked.segmentation.info["phases_from"] == "annotation"
    z = z_against_imucal(marked.calibration, ref)
    assert max(abs(v) for v in z.values()) < 1, z
    plain_map = "\n".join(line for line in LABELLED_MAP.splitlines() if "part" not in line)
    found = run(
        imported(tmp_path, labelled_session(tmp_path, label=False), plain_map),
        noise_only,
        protocol="ferraris",
    )
    assert found.segmentation.info["phases_from"] == "data"
    z = z_against_imucal(found.calibration, ref)
    assert max(abs(v) for v in z.values()) < 3, z


def test_real_session_uncut_finds_no_cut(tmp_path):
    """The whole recording, handling moves and all, is one piece: no cut is taken for a move."""
    seg = segment_log(real_log(tmp_path, annotated=False), Settings().for_protocol("ferraris"), "ferraris")
    assert seg.info["cuts"] == 0


def test_real_session_turns_read_360_after_compensation(tmp_path):
    """Each turn's angle integrated from the samples compensated by ``gyrocal apply``: the raw
    output misses a full turn by up to 12°; the compensated one reads it within 1°. A turn is
    the only observation of its column of K, so this holds by construction when the chain is
    right: it checks the integration rule (the sum over samples / 102.4 Hz, as imucal's), the
    annotation's rows and apply's path for a log without temp, not the hand."""
    from gyrocal.calibration.apply import apply_calibration

    path = real_log(tmp_path, annotated=True)
    cal = run(path, Settings().for_protocol("ferraris"), protocol="ferraris").calibration
    out = tmp_path / "compensated.parquet"
    apply_calibration(cal, path, out)
    raw, fixed = pq.read_table(path).to_pandas(), pq.read_table(out).to_pandas()
    sections = json.loads((REAL / "sections.json").read_text())
    worst_raw = 0.0
    for axis in "xyz":
        s = sections[f"{axis}_rot"]
        rows = slice(s["start"], s["end"])
        raw_angle = raw[f"gyro_{axis}"].iloc[rows].sum() / RATE
        angle = fixed[f"gyro_{axis}"].iloc[rows].sum() / RATE
        worst_raw = max(worst_raw, abs(abs(raw_angle) - 360.0))
        assert abs(abs(angle) - 360.0) < 1.0, (axis, angle)
    assert worst_raw > 5.0


# -- what a review found: annotations, gaps, timestamps, a log without temperature --------


def _annotated(tmp_path, seed=11):
    path, truth = ferraris_log(tmp_path, seed=seed, sections=True)
    return path, truth, pq.read_table(path)


def test_an_annotated_half_turn_is_refused(tmp_path):
    """A person's x_rot over half the motion reads 180°: refused, not taken for 360°."""
    path, _, table = _annotated(tmp_path)
    labels = np.array(table.column("section").to_pylist(), dtype=object)
    rows = np.flatnonzero(labels == "x_rot")
    labels[rows[len(rows) // 2 :]] = None
    table = table.set_column(
        table.schema.get_field_index("section"), "section", pa.array(list(labels), pa.string())
    )
    pq.write_table(table, path)
    with pytest.raises(SegmentationError, match=r"the x_rot section turns -?1\d\d°"):
        run(path, Settings().for_protocol("ferraris"), protocol="ferraris")


def test_a_gap_inside_a_turn_is_refused(tmp_path):
    path, truth = ferraris_log(tmp_path, seed=12)
    turn = next(t for t in truth["turns"] if t["axis"] == "y")
    middle = 0.5 * (turn["t_start"] + turn["t_end"])
    cut = _drop_rows(path, lambda t: np.abs(t - middle) > 0.06)
    with pytest.raises(SegmentationError, match=r"the turn about y has a gap of 0\.1\d* s"):
        run(cut, Settings().for_protocol("ferraris"), protocol="ferraris")


def test_annotation_is_read_with_timestamps_and_dropped_rows(tmp_path):
    """Time as a timestamp and a row dropped for a NaN: the labels still land on their rows."""
    path, _, table = _annotated(tmp_path, seed=13)
    seconds = table.column("t").to_numpy()
    stamps = pa.array((1_700_000_000 * 10**9 + np.round(seconds * 1e9)).astype(np.int64), pa.timestamp("ns"))
    table = table.set_column(0, "t", stamps)
    gyro = table.column("gyro_x").to_numpy().astype(float)
    gyro[500] = np.nan
    table = table.set_column(table.schema.get_field_index("gyro_x"), "gyro_x", pa.array(gyro))
    pq.write_table(table, path)
    result = run(
        path, settings_with(angle_uncertainty_deg=0.0, tilt_uncertainty_deg=0.0), protocol="ferraris"
    )
    assert result.segmentation.info["phases_from"] == "annotation"
    assert result.segmentation.info["rows_dropped"] == 1


def test_without_temperature_no_term_reads_a_made_up_one(tmp_path):
    """The stand-in temperature of a log without temp gives a temperature term nothing to
    fit: the term is left out of this unit's calibration, by name, with a warning."""
    path, _ = ferraris_log(tmp_path, seed=14, temperature=None)
    s = Settings.from_dict(
        {"protocols": {"ferraris": {"model": {"terms": ["bias", "scale", "misalignment", "temp_lag"]}}}}
    ).for_protocol("ferraris")
    cal = run(path, s, protocol="ferraris").calibration
    assert [t.name for t in cal.model.terms] == ["bias", "scale", "misalignment"]
    (dropped,) = cal.extra["added_terms"]
    assert not dropped["kept"] and "the log lacks what it reads" in dropped["reason"]
    assert any(w["code"] == "term_dropped" and "temp_lag" in w["message"] for w in cal.extra["warnings"])


def test_without_temperature_the_read_still_checks_the_timing(tmp_path):
    """Samples dropped across a static face are still found when the log has no temp."""
    path, truth = ferraris_log(tmp_path, seed=15, temperature=None)
    table = pq.read_table(path)
    t = table.column("t").to_numpy()
    first_turn = min(turn["t_start"] for turn in truth["turns"])
    keep = ~((np.arange(len(t)) % 10 == 5) & (t < first_turn - 3.0))
    pq.write_table(table.filter(pa.array(keep)), path)
    cal = run(path, Settings().for_protocol("ferraris"), protocol="ferraris").calibration
    assert "dropped_samples" in {w["code"] for w in cal.extra["warnings"]}


def test_a_session_without_temperature_in_the_fleet(tmp_path):
    """Through the workflow's stages (segment, analyse, report) and the fleet: the unit is
    calibrated, its report renders, and its temperature span is null, not the stand-in."""
    from gyrocal.fleet.summary import fleet_summary, fleet_table
    from gyrocal.run.stages import analyse_stage, report_stage, segment_stage

    path, _ = ferraris_log(tmp_path, seed=18, temperature=None)
    folder = tmp_path / "results" / "H1"
    meta = {"device": "H1", "batch": "B1", "session": "2026-01-01", "protocol": "ferraris"}
    settings = Settings().for_protocol("ferraris")
    segment_stage(path, folder, settings, meta)
    analyse_stage(folder, settings, meta, record_failures=False)
    report_stage(folder, tmp_path / "H1.html", settings)
    assert "temperature_not_logged" in (tmp_path / "H1.html").read_text()
    summary = fleet_summary([{"row": {**meta, "path": str(path)}, "folder": folder, "report": "H1.html"}])
    row = summary["rows"][0]
    assert row["status"] == "ok", row.get("error")
    assert row["span"] is None
    table = fleet_table(summary).to_pylist()[0]
    assert table["temperature_min"] is None and table["temperature_max"] is None
    assert "temperature_not_logged" in table["warnings"]
