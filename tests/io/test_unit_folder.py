"""A unit session's folder: the parts a job writes beside its products are one archive per
job, read where they are (loose or packed), the same bytes on every run."""

from __future__ import annotations

import json
import zipfile

import pandas as pd
import pytest

from gyrocal.io import failure
from gyrocal.io.errors import CorruptFileError
from gyrocal.io.tables import write_table
from gyrocal.io.unit_folder import (
    CONTAINERS,
    UNIT_FILES,
    job_log,
    pack,
    pack_log,
    pack_stage,
    part_exists,
    part_failure,
    read_observation_table,
    read_part_json,
    read_part_table,
)


def _validation(folder, rms: float, free_points: bool = True) -> None:
    (folder / "validation.json").write_text(
        json.dumps({"format": "gyrocal.validation/1", "summary": {"validation_rms": rms}})
    )
    write_table(
        pd.DataFrame({"temp": [20.0, 40.0], "err": [rms, -rms]}),
        folder / "validation_holds.parquet",
        {"summary": {"validation_rms": rms}},
    )
    if free_points:
        write_table(pd.DataFrame({"temp": [20.0]}), folder / "free_points.parquet", {})


def test_parts_read_the_same_loose_and_packed_and_the_archive_is_the_same_bytes_twice(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for folder in (a, b):
        folder.mkdir()
        _validation(folder, 0.5)
    loose = read_part_table(a, "holds")
    pack_stage(a, "validate")
    assert sorted(p.name for p in a.iterdir()) == ["analysis.zip"]
    packed = read_part_table(a, "holds")
    pd.testing.assert_frame_equal(packed[0], loose[0])
    assert packed[1] == loose[1]
    assert read_part_json(a, "validation")["summary"]["validation_rms"] == 0.5
    pack_stage(b, "validate")
    assert (a / "analysis.zip").read_bytes() == (b / "analysis.zip").read_bytes()
    with zipfile.ZipFile(a / "analysis.zip") as archive:
        assert sorted(archive.namelist()) == [
            "free_points.parquet",
            "validation.json",
            "validation_holds.parquet",
        ]
        assert {i.date_time for i in archive.infolist()} == {(1980, 1, 1, 0, 0, 0)}


def test_a_stage_replaces_its_own_parts_and_keeps_the_others(tmp_path):
    _validation(tmp_path, 0.5)
    (tmp_path / "diagnosis.json").write_text('{"format": "gyrocal.diagnosis/1", "verdict": "first"}')
    pack(tmp_path)
    # the validation again, with a model that has no free points: its old ones leave
    _validation(tmp_path, 0.25, free_points=False)
    pack_stage(tmp_path, "validate")
    assert read_part_json(tmp_path, "validation")["summary"]["validation_rms"] == 0.25
    assert not part_exists(tmp_path, "free_points")
    assert read_part_json(tmp_path, "diagnosis")["verdict"] == "first"  # another stage's part


def test_failure_records_travel_inside_the_archive(tmp_path):
    rec = failure.record("fit", "the fit failed", {"device": "U1"})
    failure.write([tmp_path / UNIT_FILES[k] for k in ("validation", "holds")], rec)
    pack_stage(tmp_path, "validate")
    assert part_failure(tmp_path, "validation") == rec == part_failure(tmp_path, "holds")
    with pytest.raises(failure.UpstreamFailure, match="fit failed: the fit failed"):
        read_part_json(tmp_path, "validation")


def test_a_missing_or_broken_part_names_the_archive_and_the_part(tmp_path):
    _validation(tmp_path, 0.5)
    pack_stage(tmp_path, "validate")
    with pytest.raises(CorruptFileError, match=r"analysis\.zip/by_temperature\.parquet: no such file"):
        read_part_table(tmp_path, "by_temperature")
    (tmp_path / "segmentation.zip").write_bytes(b"PK not an archive")
    with pytest.raises(CorruptFileError, match=r"segmentation\.zip: not a readable archive"):
        read_part_table(tmp_path, "timeline")


def test_every_part_belongs_to_one_archive():
    parts = [k for keys in CONTAINERS.values() for k in keys]
    assert len(parts) == len(set(parts))
    assert set(UNIT_FILES) - set(parts) == {"calibration"}  # the calibration stays a file


def test_a_job_log_joins_its_archive_and_the_other_parts_stay_as_they_were(tmp_path):
    _validation(tmp_path, 0.5)
    pack_stage(tmp_path, "validate")
    before = {n: read_part_table(tmp_path, "holds")[0] for n in ("holds",)}
    log = tmp_path / "analyse.log"
    log.write_text("fit -> calibration.json\n")
    assert pack_log(tmp_path, "analyse", log)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["analysis.zip"]
    assert job_log(tmp_path, "analyse") == "fit -> calibration.json\n"
    pd.testing.assert_frame_equal(read_part_table(tmp_path, "holds")[0], before["holds"])
    # no archive to join (the job ended before it wrote one): the log stays, readable
    seg = tmp_path / "segment.log"
    seg.write_text("segment failed\n")
    assert not pack_log(tmp_path, "segment", seg)
    assert seg.exists() and job_log(tmp_path, "segment") == "segment failed\n"


def test_observations_are_read_packed_and_a_failure_record_there_is_passed_on(tmp_path):
    obs = pd.DataFrame({"temp": [20.0, 40.0], "gyro_x": [0.1, 0.2]})
    write_table(obs, tmp_path / "observations.parquet", {"info": {"noise": {"static_seconds": 12.5}}})
    pack_stage(tmp_path, "segment")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["segmentation.zip"]
    for where in (tmp_path, tmp_path / "observations.parquet"):  # the folder, or the part's path
        read, extra = read_observation_table(where)
        pd.testing.assert_frame_equal(read, obs)
        assert read.attrs["static_seconds"] == 12.5
    rec = failure.record("segment", "no hold passed the checks", {"device": "U1"})
    failure.write([tmp_path / "observations.parquet"], rec)
    pack_stage(tmp_path, "segment")
    with pytest.raises(failure.UpstreamFailure, match="segment failed: no hold passed the checks"):
        read_observation_table(tmp_path)
