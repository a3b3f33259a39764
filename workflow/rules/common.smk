# Shared by every rule: the manifest as a dict, wildcard patterns, settings as parameters.
# Kept cheap: it runs whenever the workflow plans, for every unit of the fleet.
import json
import os
import shlex
import sys

from gyrocal import __version__ as GYROCAL_VERSION
from gyrocal.manifest import (
    BATCH_PATTERN,
    DEVICE_PATTERN,
    SESSION_PATTERN,
    read_manifest,
)


envvars:
    "PATH",


# Jobs run `python -m gyrocal` from this workflow's source. Without --use-conda the
# interpreter running Snakemake comes first on PATH; with it, the rule's conda env does.
os.environ["PATH"] = (
    os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
)
GYROCAL = f"PYTHONPATH={shlex.quote(workflow.basedir)}${{PYTHONPATH:+:$PYTHONPATH}} python -m gyrocal"
ENV = "../envs/gyrocal.yaml"
DEMO_LOGS = os.path.normpath(config["demo"]["folder"])
UNITS = {
    (row["batch"], row["device"], row["session"]): row
    for row in read_manifest(config["devices"])
}
# Settings travel as parameters, so changing one re-runs the jobs that read it.
SEGMENTATION = json.dumps({"segmentation": config["segmentation"]}, sort_keys=True)
MODEL = json.dumps({"model": config["model"]}, sort_keys=True)


wildcard_constraints:
    batch=BATCH_PATTERN,
    device=DEVICE_PATTERN,
    session=SESSION_PATTERN,


def unit(wildcards):
    return UNITS[(wildcards.batch, wildcards.device, wildcards.session)]


def log_input(wildcards):
    """The unit's log as an input when it exists or the demo can make it; otherwise none,
    so that the segment stage records the missing file as this unit's failure instead
    of stopping the fleet."""
    path = unit(wildcards)["log"]
    if os.path.exists(path) or os.path.dirname(path).startswith(DEMO_LOGS + os.sep):
        return path
    return []


def unit_args(wildcards):
    row = unit(wildcards)
    return " ".join(
        f"--{key} {shlex.quote(row[key])}"
        for key in ("device", "batch", "session", "protocol")
    )


def unit_reports():
    return [f"reports/{b}/{d}/{s}.html" for (b, d, s) in UNITS]


def unit_files(name):
    return [f"results/{b}/{d}/{s}/{name}" for (b, d, s) in UNITS]
