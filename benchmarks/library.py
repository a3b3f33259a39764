"""Benchmark: a library call beside the command line, whole processes, imports included.

On one log (the full seed-000 turntable protocol at 100 Hz, made by benchmarks/process.py's
cache, or ``--log``) each round starts, one after the other:

* cli      — ``python -m gyrocal diagnose LOG -o OUT`` (the same with ``calibrate``);
* library  — ``python -c "import numpy, gyrocal; gyrocal.diagnose(LOG).save(OUT)"``: numpy
             imported first, as in a notebook, so BLAS starts with its own thread count
             and the call itself must bring it to one (threadpoolctl) and back.

Printed per command: the median and range of each process's wall time and of the paired
ratio library ÷ cli, with the machine, the date and the load average. The two files are
compared byte for byte.

    python benchmarks/library.py [--repeat 3] [--only diagnose] [--log LOG]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from host import cores, cpu_name
from process import log_at

COMMANDS = ("calibrate", "diagnose")
LIBRARY = "import sys, numpy, gyrocal; gyrocal.{command}(sys.argv[1]).save(sys.argv[2])"


def timed(argv: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, env=env)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--only", default=",".join(COMMANDS))
    parser.add_argument("--log", type=Path, help="the log (default: the 100 Hz full protocol)")
    args = parser.parse_args()
    log = args.log or log_at(100.0)
    # BLAS as a notebook finds it: no thread count set in the environment
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    print(f"{cpu_name()}, {cores()}, {dt.datetime.now():%Y-%m-%d %H:%M}, log {log}")
    with tempfile.TemporaryDirectory() as scratch:
        for command in args.only.split(","):
            cli_out, lib_out = Path(scratch) / "cli.json", Path(scratch) / "lib.json"
            cli, lib = [], []
            for _ in range(args.repeat):
                cli.append(
                    timed([sys.executable, "-m", "gyrocal", command, str(log), "-o", str(cli_out)], env)
                )
                code = LIBRARY.format(command=command)
                lib.append(timed([sys.executable, "-c", code, str(log), str(lib_out)], env))
            ratios = [b / a for a, b in zip(cli, lib, strict=True)]
            same = cli_out.read_bytes() == lib_out.read_bytes()
            print(
                f"{command:>9}: cli {statistics.median(cli):.2f} s ({min(cli):.2f}-{max(cli):.2f}), "
                f"library {statistics.median(lib):.2f} s ({min(lib):.2f}-{max(lib):.2f}), "
                f"library / cli {statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}); "
                f"files {'identical' if same else 'DIFFER'}; load {os.getloadavg()[0]:.1f}"
            )


if __name__ == "__main__":
    main()
