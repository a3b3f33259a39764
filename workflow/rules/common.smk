# Shared by every rule: the manifest as a dict, wildcard patterns, settings as parameters.
# Kept cheap: it runs whenever the workflow plans, for every unit of the fleet.
import gc
import json
import os
import shlex
import sys

from gyrocal import __version__ as GYROCAL_VERSION
from gyrocal.fleet.manifest import (
    BATCH_PATTERN,
    DEVICE_PATTERN,
    SESSION_PATTERN,
    model_entry,
    read_manifest,
)
from gyrocal.calibration.registry import HISTORY_NAME, plan_history
from gyrocal.fleet.summary import drift_devices, other_sessions
from gyrocal.io.errors import or_exit
from gyrocal.protocols import registry

# Planning builds millions of small objects (jobs, files, wildcards) that live until
# Snakemake exits, and Python's cyclic collector at its default thresholds scans them
# again and again: a fifth of the time to plan 10,000 units (docs/cluster.md). What
# exists after parsing is left out of its scans and it runs far less often; the jobs'
# own processes keep Python's defaults.
gc.freeze()
gc.set_threshold(100_000, 50, 1000)


envvars:
    "PATH",


# Jobs run `python -m gyrocal` from this workflow's source. Without --use-conda the
# interpreter running Snakemake comes first on PATH; with it, the rule's conda env does.
os.environ["PATH"] = (
    os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
)
GYROCAL = f"PYTHONPATH={shlex.quote(workflow.basedir)}${{PYTHONPATH:+:$PYTHONPATH}} python -m gyrocal"
# A unit's segment, analyse and report jobs run under gyrocal.run.guard: at a limit of the
# config's job_limits it ends the stage and records the unit's failure with the reason.
GUARD = f"PYTHONPATH={shlex.quote(workflow.basedir)}${{PYTHONPATH:+:$PYTHONPATH}} python -m gyrocal.run.guard"
ENV = "../envs/gyrocal.yaml"
DEMO_LOGS = os.path.normpath(config["demo"]["folder"])
# Real recordings the demo imports with `gyrocal import` (data/real/<name>/: the recording,
# its import map and its licence), as demo/real/<name>.parquet.
REAL_LOGS = os.path.normpath("demo/real")
# A bad manifest, models: entry or registry stops the plan with its one line (or_exit).
UNITS = {
    (row["batch"], row["device"], row["session"]): row
    for row in or_exit(read_manifest, config["devices"])
}
# Models of their own (config models:): the entry each unit takes, None for the fleet's.
# Only a unit whose entry changes gets new settings, so only its analysis re-runs.
MODELS = config.get("models") or {}
MODEL_ENTRY = {
    key: or_exit(model_entry, row, MODELS, source=config["devices"])
    for key, row in UNITS.items()
}
# Devices with two or more turntable sessions get a drift page, counting the sessions of
# earlier runs into this results folder that the registry holds. The plan asks the registry
# once and records the answer in results/drift_history.jsonl (rewritten only when it
# changes: the fleet job's input, so a changed history makes the pages again); a
# scheduler's jobs, which parse this file again, read the record instead.
HISTORY = or_exit(
    plan_history,
    "results",
    config.get("registry"),
    {row["device"] for row in UNITS.values()},
    {(device, session) for _, device, session in UNITS},
    query=workflow.is_main_process,
)
DRIFT_DEVICES = drift_devices(UNITS.values(), HISTORY)
# The diagnosis judges a unit's candidates on another session of the same device.
OTHER_SESSION = other_sessions(UNITS.values())
# Settings travel as parameters, so changing one re-runs the jobs that read it.
# A servo or sweep unit also gets its protocol's section (config `protocols:`).
SEGMENTATION = {"segmentation": config["segmentation"]}
# The user's own term files are inputs: editing one re-runs what fits with it.
TERM_FILES = config["model"].get("term_files", []) + [
    path
    for section in config.get("protocols", {}).values()
    for path in (section or {}).get("model", {}).get("term_files", [])
]


# How many attempts a job has (the profiles retry a job the scheduler ended, once, with
# doubled resources), for gyrocal.run.guard: on the last, it records a unit whose stage would
# outrun its SLURM job's time or memory, so that the fleet summary still comes. Known when
# the run starts, in the main process, whose environment its jobs inherit (sbatch
# --export=ALL); each job's own attempt is its `attempt` resource, in its command. The
# memory is the job's only when the SLURM executor runs it (not a local run inside an
# allocation, where nothing enforces the rule's mem_mb).
onstart:
    os.environ.update(GYROCAL_ATTEMPTS=str(workflow.execution_settings.retries + 1))
    if getattr(workflow.executor_plugin, "name", None) == "slurm":
        os.environ.update(GYROCAL_SLURM_MEMORY="1")


wildcard_constraints:
    batch=BATCH_PATTERN,
    device=DEVICE_PATTERN,
    session=SESSION_PATTERN,


def unit(wildcards):
    return UNITS[(wildcards.batch, wildcards.device, wildcards.session)]


def limit_options(limits):
    return " ".join(
        f"--{key.replace('_', '-')} {limits[key]:g}"
        for key in ("memory_mb", "timeout_s")
        if limits.get(key) is not None
    )


# The guard's options per device: a parameter, so raising a device's limit re-runs its
# jobs (a unit that failed on it gets another chance), and only its.
LIMITS = limit_options(config["job_limits"])
DEVICE_LIMITS = {
    device: limit_options({**config["job_limits"], **own})
    for device, own in config["job_limits"]["devices"].items()
}


def job_limits(wildcards):
    return DEVICE_LIMITS.get(wildcards.device, LIMITS)


def other_segmentation(wildcards):
    other = OTHER_SESSION.get((wildcards.batch, wildcards.device, wildcards.session))
    return (
        []
        if other is None
        else [f"results/{other[0]}/{other[1]}/{other[2]}/segmentation.zip"]
    )


def other_session_option(wildcards, input):
    return (
        f"--other-session {shlex.quote(os.path.dirname(input.other[0]))}"
        if input.other
        else ""
    )


def log_input(wildcards):
    """The unit's log as an input when it exists or the demo can make it; otherwise none,
    so that the segment stage records the missing file as this unit's failure instead
    of stopping the fleet. A URL in the manifest is a log in object storage, which
    Snakemake retrieves before the segment job runs."""
    path = unit(wildcards)["log"]
    if "://" in path:
        return storage_log(path)
    if (
        os.path.exists(path)
        or os.path.dirname(path).startswith(DEMO_LOGS + os.sep)
        or os.path.dirname(path) == REAL_LOGS
    ):
        return path
    return []


def storage_log(url):
    """A log's URL as a storage input: ``s3://bucket/key`` (or any scheme a storage plugin
    accepts) through the plugin Snakemake infers from it; ``fs:///path`` through the fs
    plugin, whose queries are plain paths (a folder every node mounts)."""
    scheme, _, rest = url.partition("://")
    if scheme == "fs":
        return storage.fs(rest)
    return storage(url)


# What a servo or sweep job reads besides its protocol's defaults (the Protocol's
# defaults): the turntable's model and ladder are not theirs, so changing those
# leaves their jobs alone. (A servo calibration is seed 001's six parameters: of the
# analysis, only its diagnosis reads the model.)
PROTOCOL_READS = {
    "segment": ("options",),
    "report": ("options", "model", "diagnosis"),  # the analyse job, which reports too
}


def protocol_settings(settings, stage, protocol, entry=None):
    """The settings a ``protocol`` unit's ``stage`` job reads, as JSON (part of a
    parameter: when it changes, the job re-runs); ``entry``, the key of the config's
    ``models:`` entry the unit takes, goes with its analysis."""
    if entry is not None and "model" in PROTOCOL_READS[stage]:
        settings = {**settings, "unit": {"entry": entry, "model": MODELS[entry]}}
    if registry.get(protocol).top_level_settings:
        return json.dumps(settings, sort_keys=True)
    reads = PROTOCOL_READS[stage]
    own = {}
    user_terms = {
        k: config["model"][k]
        for k in ("term_files", "expressions")
        if config["model"].get(k)
    }
    if "model" in reads and user_terms:
        own["model"] = user_terms
    if "diagnosis" in reads:
        own["diagnosis"] = {"significance": config["diagnosis"]["significance"]}
    section = config.get("protocols", {}).get(protocol) or {}
    section = {k: v for k, v in section.items() if k in reads}
    if section:
        own["protocols"] = {protocol: section}
    if "unit" in settings:
        own["unit"] = settings["unit"]
    return json.dumps(own, sort_keys=True)


def stage_args(settings, stage):
    """A function of the unit giving the arguments of its ``stage`` job besides files:
    who the unit is and the settings its protocol reads. One parameter, not one per
    argument: Snakemake inspects every callable parameter of every job as it plans, which
    with seven per unit was a sixth of the time to plan 10,000 units (docs/cluster.md).
    The settings are the same for every unit of a protocol and model entry, so each is
    written once."""
    quoted = {}

    def args(wildcards):
        row = unit(wildcards)
        protocol = row["protocol"]
        entry = MODEL_ENTRY[(wildcards.batch, wildcards.device, wildcards.session)]
        if (protocol, entry) not in quoted:
            quoted[protocol, entry] = shlex.quote(
                protocol_settings(settings, stage, protocol, entry)
            )
        return (
            " ".join(
                f"--{key} {shlex.quote(row[key])}"
                for key in ("device", "batch", "session", "protocol")
            )
            + " --settings-json "
            + quoted[protocol, entry]
        )

    return args


SEGMENT_ARGS = stage_args(SEGMENTATION, "segment")


def segment_args(wildcards, input):
    """The log to segment, then the unit and its settings. The log is Snakemake's local
    copy of one in storage, the manifest's path otherwise: a missing log has no input,
    and the stage records it as the unit's failure."""
    log = input.log or unit(wildcards)["log"]
    return f"{shlex.quote(log)} {SEGMENT_ARGS(wildcards)}"


def demo_unit_options(wildcards):
    """Simulator options of a demo unit: its protocol, effects beyond the default model,
    its mounts."""
    settings = config["demo"].get("units", {}).get(wildcards.device, {})
    protocol = unit(wildcards)["protocol"]
    options = [f"--protocol {protocol}"]
    # The demo's top-level set points and rates, like the config's top-level settings, are
    # the default protocol's (the turntable's).
    if registry.get(protocol).top_level_settings:
        for key in ("temperatures", "rates"):
            values = ",".join(str(v) for v in config["demo"][key])
            options.append(f"--{key}={values}")
    if settings.get("mounts"):
        options.append(f"--mounts={shlex.quote(','.join(settings['mounts']))}")
    if settings.get("soak_s"):
        options.append(f"--soak-s={settings['soak_s']}")
    noise = settings.get("noise")
    if noise:
        noise = noise if isinstance(noise, str) else json.dumps(noise, sort_keys=True)
        options.append(f"--noise {shlex.quote(noise)}")
    shift = settings.get("bias_shift", {}).get(wildcards.session)
    if shift:
        options.append("--bias-shift=" + ",".join(str(v) for v in shift))
    if settings.get("effects"):
        effects = json.dumps(settings["effects"], sort_keys=True)
        options.append(f"--effects {shlex.quote(effects)}")
    return " ".join(options)


def unit_reports():
    return [f"reports/{b}/{d}/{s}.html" for (b, d, s) in UNITS]
