"""Logs in object storage: a manifest URL is kept as written, the workflow retrieves the log
through Snakemake's storage plugin and calibrates it as it does from a plain path. Tested
against a local S3-compatible server (moto's, with snakemake-storage-plugin-s3) and with the
fs provider (snakemake-storage-plugin-fs, which copies with rsync)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from gyrocal.calibration.file import load_calibration
from gyrocal.fleet.manifest import read_manifest
from gyrocal.io.unit_folder import read_part_table
from gyrocal.simulate import GyroUnit, TurntableProtocol, simulate_unit

from .conftest import needs, snakemake

UNIT = ("B1", "A1", "2026-01-01")
FOLDER = "results/{}/{}/{}".format(*UNIT)
# The unit's calibration and what is made with it (segment, then fit, validate, diagnose).
TARGETS = [f"{FOLDER}/{name}" for name in ("calibration.json", "analysis.zip")]
CONFIG = "devices: devices.tsv\nmodel: {terms: [bias, scale, misalignment]}\n"

needs_storage = needs(
    {
        "snakemake-storage-plugin-fs": importlib.util.find_spec("snakemake_storage_plugin_fs") is not None,
        "rsync": shutil.which("rsync") is not None,
    },
    "the fs storage provider needs both: a test extra; Debian's rsync, which make test installs where it can",
)


def fleet(folder, path):
    folder.mkdir()
    (folder / "devices.tsv").write_text(
        f"device\tbatch\tsession\tprotocol\tpath\n{UNIT[1]}\t{UNIT[0]}\t{UNIT[2]}\tturntable\t{path}\n"
    )
    (folder / "config.yaml").write_text(CONFIG)
    return folder


def test_a_url_in_the_manifest_is_kept_as_written_and_a_path_is_resolved(tmp_path):
    (tmp_path / "line3").mkdir()
    manifest = tmp_path / "line3" / "devices.tsv"
    manifest.write_text(
        "device\tbatch\tsession\tprotocol\tpath\n"
        "A1\tB1\t2026-01-01\tturntable\ts3://rig-logs/line3//A1.parquet\n"
        "A2\tB1\t2026-01-01\tturntable\tfs:///store/line3/A2.parquet\n"
        "A3\tB1\t2026-01-01\tturntable\t../rig/./A3.parquet\n"
    )
    logs = [row["log"] for row in read_manifest(manifest)]
    assert logs == [
        "s3://rig-logs/line3//A1.parquet",
        "fs:///store/line3/A2.parquet",
        str(tmp_path / "rig" / "A3.parquet"),
    ]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """One quick simulated log in a storage folder, calibrated by the workflow twice: the
    manifest naming its path, and naming it as an fs:// URL."""
    base = tmp_path_factory.mktemp("storage")
    log = base / "store" / "line3" / "A1-2026-01-01.parquet"
    log.parent.mkdir(parents=True)
    simulate_unit(
        log,
        rig=TurntableProtocol.quick(temperatures=(0.0, 20.0, 40.0)),
        unit=GyroUnit.seed000(),
        rng=np.random.default_rng(5),
        device=UNIT[1],
        seed=5,
    )
    plain, remote = fleet(base / "plain", log), fleet(base / "remote", f"fs://{log}")
    outputs = {}
    for folder in (plain, remote):
        out = snakemake(folder, *TARGETS)
        assert out.returncode == 0, out.stderr[-3000:]
        outputs[folder.name] = out.stdout + out.stderr
    return plain, remote, outputs, log


@pytest.mark.slow
@needs_storage
def test_a_log_in_storage_is_retrieved_and_calibrated_as_from_its_path(runs):
    plain, remote, outputs, log = runs
    assert f"Retrieving from storage: {log}" in outputs["remote"]
    assert "Retrieving from storage" not in outputs["plain"]
    # gyrocal read Snakemake's local copy, not the storage folder (which, for the fs
    # provider alone, it could also have read directly)
    _, extra = read_part_table(remote / FOLDER, "observations")
    assert extra["log"].startswith(os.path.join(".snakemake", "storage", "fs", ""))
    assert extra["log"].endswith(str(log))
    for target in TARGETS:
        assert (remote / target).read_bytes() == (plain / target).read_bytes(), target
    cal = load_calibration(remote / FOLDER / "calibration.json")
    assert (cal.meta["batch"], cal.meta["device"], cal.meta["session"]) == UNIT


@pytest.mark.slow
@needs_storage
def test_the_second_plan_finds_nothing_to_do(runs):
    """Snakemake asks the storage for the log's time stamp: unchanged, nothing re-runs."""
    _, remote, _, _ = runs
    out = snakemake(remote, "--dry-run", *TARGETS)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Nothing to be done" in out.stdout + out.stderr


@needs_storage
def test_a_missing_object_stops_the_plan_naming_it(tmp_path):
    """Unlike a missing local log (its unit's failure, recorded), a URL is asked of the
    storage when the workflow plans: Snakemake stops and names the object."""
    url = f"fs://{tmp_path / 'store' / 'absent.parquet'}"
    out = snakemake(fleet(tmp_path / "plan", url), "--dry-run")
    text = out.stdout + out.stderr
    assert out.returncode != 0
    assert "Missing input files for rule segment" in text
    assert f"{tmp_path / 'store' / 'absent.parquet'} (in storage)" in text


needs_s3 = needs(
    {
        name: importlib.util.find_spec(module) is not None
        for name, module in (
            ("snakemake-storage-plugin-s3", "snakemake_storage_plugin_s3"),
            ("moto", "moto"),
            ("flask", "flask"),
            ("flask-cors", "flask_cors"),
        )
    },
    "test extras",
)


@pytest.fixture(scope="module")
def s3_server():
    """moto's S3-compatible server on a free local port, with the bucket ``rig-logs``."""
    import boto3

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    server = subprocess.Popen(
        [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        for _ in range(200):
            try:
                socket.create_connection(("127.0.0.1", port), 0.2).close()
                break
            except OSError:
                time.sleep(0.1)
        url = f"http://127.0.0.1:{port}"
        client = boto3.client(
            "s3",
            endpoint_url=url,
            aws_access_key_id="line3",
            aws_secret_access_key="secret",
            region_name="us-east-1",
        )
        client.create_bucket(Bucket="rig-logs")
        yield url, client
    finally:
        server.terminate()
        server.wait(10)


@pytest.mark.slow
@needs_storage  # the fs run is its reference
@needs_s3
def test_a_log_in_s3_is_retrieved_and_calibrated_as_from_its_path(runs, s3_server, tmp_path):
    plain, _, _, log = runs
    url, client = s3_server
    client.upload_file(str(log), "rig-logs", "line3/A1-2026-01-01.parquet")
    remote = fleet(tmp_path / "s3", "s3://rig-logs/line3/A1-2026-01-01.parquet")
    options = [
        "--storage-s3-endpoint-url",
        url,
        "--storage-s3-access-key",
        "line3",
        "--storage-s3-secret-key",
        "secret",
    ]
    out = snakemake(remote, *TARGETS, *options)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Retrieving from storage: s3://rig-logs/line3/A1-2026-01-01.parquet" in out.stdout + out.stderr
    _, extra = read_part_table(remote / FOLDER, "observations")
    assert extra["log"] == os.path.join(
        ".snakemake", "storage", "s3", "rig-logs", "line3", "A1-2026-01-01.parquet"
    )
    for target in TARGETS:
        assert (remote / target).read_bytes() == (plain / target).read_bytes(), target
    again = snakemake(remote, "--dry-run", *TARGETS, *options)
    assert again.returncode == 0 and "Nothing to be done" in again.stdout + again.stderr
