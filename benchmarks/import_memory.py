"""Benchmark: ``gyrocal import`` streams, so its memory does not grow with the file.

Writes rig-like CSV files (a sample index, gyro in rad/s, accelerometer in m/s², a
temperature; five significant digits, as loggers print) of each size asked, a block at a
time, into a cache outside the repository (``$GYROCAL_BENCH_CACHE``, else
``~/.cache/gyrocal/benchmarks``), then imports each in a fresh process and prints its wall
time and peak resident memory (its own ``ru_maxrss``, from ``wait4``) beside the file's
size, and the same for a process that only imports gyrocal's command line (the floor).
With ``--bag N`` it does the same for a rosbag2 (sqlite3) of N Imu messages.

    python benchmarks/import_memory.py [--rows 1000000,5000000] [--bag 0]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from host import cores, cpu_name

ROOT = Path(__file__).resolve().parents[1]
CACHE = Path(os.environ.get("GYROCAL_BENCH_CACHE", Path.home() / ".cache" / "gyrocal" / "benchmarks"))
MAP = """time: {column: n, sample_rate: 1000}
gyro: {x: wx, y: wy, z: wz, unit: rad/s}
accel: {x: ax, y: ay, z: az, unit: m/s^2}
temp: {column: temp, unit: degC}
"""
CHUNK = 500_000


def make_csv(rows: int) -> Path:
    path = CACHE / f"import_{rows}.csv"
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(rows)
    tmp = path.with_suffix(".tmp")
    writer = None
    for start in range(0, rows, CHUNK):
        n = min(CHUNK, rows - start)
        data = {"n": np.arange(start, start + n)}
        data.update({f"w{a}": np.round(rng.normal(0, 0.5, n), 5) for a in "xyz"})
        data.update({f"a{a}": np.round(rng.normal(0, 0.3, n) + (9.81 if a == "z" else 0), 4) for a in "xyz"})
        data["temp"] = np.round(25 + np.arange(start, start + n) * 1e-6, 3)
        table = pa.table(data)
        if writer is None:
            writer = pacsv.CSVWriter(tmp, table.schema)
        writer.write_table(table)
    writer.close()
    tmp.rename(path)
    return path


def make_bag(messages: int) -> Path:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    path = CACHE / f"import_bag_{messages}"
    if path.exists():
        return path
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    cov = np.zeros(9)
    rng = np.random.default_rng(messages)
    tmp = CACHE / f"import_bag_{messages}.tmp"
    with Writer(tmp, version=9) as writer:
        conn = writer.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        for i in range(messages):
            ns = 1_700_000_000 * 10**9 + i * 10**6
            w = rng.normal(0, 0.5, 3)
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](
                    stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                    frame_id="imu",
                ),
                orientation=T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
                orientation_covariance=cov,
                angular_velocity=T["geometry_msgs/msg/Vector3"](*w),
                angular_velocity_covariance=cov,
                linear_acceleration=T["geometry_msgs/msg/Vector3"](0.0, 0.0, 9.81),
                linear_acceleration_covariance=cov,
            )
            writer.write(conn, ns, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))
    tmp.rename(path)
    return path


def measure(args: list[str]) -> tuple[float, float]:
    """Wall seconds and peak RSS (MiB) of one process."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, *args], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    if status:
        raise SystemExit(f"failed: {' '.join(args)}")
    return time.perf_counter() - start, usage.ru_maxrss / 1024


def size_of(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*")) if path.is_dir() else path.stat().st_size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", default="1000000,5000000", help="CSV sizes, comma-separated")
    parser.add_argument("--bag", type=int, default=0, help="also a bag of this many Imu messages")
    args = parser.parse_args()
    print(f"gyrocal import, peak memory: {cpu_name()}, {cores()}, {dt.date.today()}")
    _, floor = measure(["-c", "import gyrocal.run.cli, gyrocal.importer.tabular"])
    print(f"  floor (python + gyrocal's command line imported): {floor:.0f} MiB")
    sources = [(make_csv(int(r)), int(r)) for r in args.rows.split(",") if r]
    if args.bag:
        sources.append((make_bag(args.bag), args.bag))
    with tempfile.TemporaryDirectory() as scratch:
        map_path = Path(scratch) / "map.yaml"
        map_path.write_text(MAP)
        for source, rows in sources:
            out = Path(scratch) / "out.parquet"
            extra = [] if source.is_dir() else ["--map", str(map_path)]
            wall, peak = measure(["-m", "gyrocal", "import", str(source), "-o", str(out), *extra])
            mib = size_of(source) / 2**20
            print(
                f"  {source.name}: {rows / 1e6:g} M rows, {mib:.0f} MiB in, "
                f"{out.stat().st_size / 2**20:.0f} MiB out: {wall:.1f} s "
                f"({rows / wall / 1e6:.2f} M rows/s), peak RSS {peak:.0f} MiB "
                f"({peak - floor:+.0f} MiB over the floor)"
            )


if __name__ == "__main__":
    main()
