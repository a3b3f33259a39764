"""Benchmark: does a fix the diagnosis offers for one unit harm the other units of its batch?

The diagnosis judges a term on the unit it was run on. A batch is calibrated with one
model, so a term added for one unit is fitted on every unit, including those that lack the
effect. This measures what that does to them.

For each case of ``benchmarks/diagnosis.py``'s ``CASES`` (those with an effect to fix: not
"none" or "mounting", not servo, whose calibration is not the common model):

* the carrier: the case's zoo unit, seed 0; session 0 is diagnosed with session 1 as the
  other session, as ``benchmarks/diagnosis.py`` does. The offered fix is ``best``, else an
  offered first ``partial``: its term and its ``together`` terms, or its whole ``model``
  where it offers one (a continuous model instead of the grid). No offer: listed, skipped.
* the others: N zoo units of the same zoo protocol, effect "none", white noise, seeds
  101..100+N, session 0, written with the carrier's session-0 arguments (rate, ramp, the
  case's unit and session-0 overrides, which describe the rig). They are the same units for
  every case with the same protocol and overrides, so their logs, observations and default
  calibrations are made once per worker and kept.

Every unit is calibrated with the batch's model and with the fix added to it, and on each
of the others the two are compared. The batch's model is the protocol's default, but for a
sweep, whose complete zoo units need a quadratic bias the default lacks (``BATCH_TERMS``):
without it every fix for a sweep would be judged on units the batch's model already
misses. Cases whose effect is ``none`` are the batch itself and are not judged.

* end of line: ``gyrocal.fleet.eol.judge`` against limits of the batch's own
  (:func:`batch_limits`: twice the largest value and temperature coefficient of each
  parameter over its complete units without the fix, the held-out error within 1.5 times
  the floor), with the segmentation info: does ``passed`` change, and which checks flip
  (the demo's spec in ``config/config.yaml`` fails every zoo unit whatever the fix);
* the parameters at the reference temperature (``parameters_at``), each present in both:
  Δ = with − without over the standard error without, with, and the Hausman-type
  Δ / sqrt(max(σ_with² − σ_without², 1e-6 σ_with²)) (a term a unit does not need should
  move nothing beyond what its extra freedom explains; where σ does not grow the floor is
  the denominator and the figure says nothing, so its maximum is also given where σ grew);
  beyond 1, 2, 3 σ_with counted per unit;
* the held-out excess (validation RMS ÷ noise floor) without and with;
* what the calibration file records of the added terms (``extra["added_terms"]``: kept or
  dropped, why) and its ``warnings``, where it has them ("—" where it has no such record).

A calibration that raises ``GyrocalError`` counts as failed, its message kept; one whose
validation raises is compared on its parameters and end-of-line checks, not its excess.

    .venv/bin/python benchmarks/fix_batch.py [--others 19] [--cases all|smallest] [--jobs 2] [--out FILE.json]

``smallest``: the cases of ``benchmarks/diagnosis.py``'s ``SMALLEST`` that are judged here,
with "warmup turntable3". Prints one Markdown row per case, totals, and a table of the
other figures; ``--out`` writes every row with its per-unit details as JSON.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from diagnosis import CASES, RATE_HZ, SMALLEST, label  # noqa: E402

FIRST_OTHER_SEED = 101
SIGMAS = (1, 2, 3)
TINY = 1e-6  # the Hausman denominator's floor, as a share of σ_with²

# Per worker process: the others' figures with the default settings, by batch key.
_BATCHES: dict = {}


# What a batch's complete units need beyond the protocol's default model: the zoo's bias is
# quadratic in temperature, which a sweep's default (linear) model lacks, and the diagnosis
# names bias_temp_poly on its complete sweeps (docs/benchmarks.md). A fix is judged on top.
BATCH_TERMS = {"sweep": ("bias_temp_poly",)}


def judged(case) -> bool:
    return case[0] != "none" and case[3] not in ("none", "mounting") and case[1] != "servo"


def batch_settings(gyrocal_protocol: str):
    from gyrocal.diagnosis import extended
    from gyrocal.pipeline.config import Settings

    settings = Settings().for_protocol(gyrocal_protocol)
    for term in BATCH_TERMS.get(gyrocal_protocol, ()):
        settings = extended(settings, term)
    return settings


def _overrides(case):
    """(unit overrides, per-session overrides for sessions 0 and 1), as diagnosis.run_case."""
    unit = case[4] if len(case) > 4 else {}
    sessions = case[5] if len(case) > 5 else {}
    by_session = bool(sessions) and all(isinstance(k, int) for k in sessions)
    return unit, {s: sessions.get(s, {}) if by_session else sessions for s in (0, 1)}


def _session_args(protocol: str, session: int, overrides: dict) -> dict:
    ramp = {"ramp_c_per_h": (30.0, 60.0)[session]} if protocol == "sweep" else {}
    return {"rate_hz": RATE_HZ.get(protocol, 25.0), **ramp, **overrides}


def _gyrocal_protocol(protocol: str) -> str:
    return "turntable" if protocol.startswith("turntable") else protocol


# The batch's own limits: the demo line's spec fails every zoo unit (another sensor: biases
# of 0.4 deg/s, scales 1 % off, a span of -20 to 55 °C), so its verdicts could not change.
# A line sets limits with a margin around its population: here twice the largest value (and
# temperature coefficient) of each parameter over the batch's complete units calibrated
# without the fix, and the held-out error within 1.5 times the floor, as the demo's spec.
MARGIN = 2.0
EXCESS_LIMIT = 1.5


def batch_limits(units: list):
    """:class:`SpecLimits` for the batch from its complete units' calibrations without the
    fix (``units``: their figures, each with its ``cal``)."""
    from gyrocal.calibration.parameters import parameters_at, temperature_coefficients
    from gyrocal.fleet.limits import SpecLimits

    params, slopes = {}, {}
    judged = ("bias.", "scale.", "misalignment.")  # what a line's spec limits, as the demo's
    for figures in units:
        cal = figures.get("cal")
        if cal is None:
            continue
        for name, value in parameters_at(cal)[["parameter", "value"]].itertuples(index=False):
            if name.startswith(judged):
                params[name] = max(params.get(name, 0.0), abs(float(value)))
        tc = temperature_coefficients(cal)
        for name, value in [] if tc is None else tc[["parameter", "value"]].itertuples(index=False):
            if name.startswith(judged):
                slopes[name] = max(slopes.get(name, 0.0), abs(float(value)))
    nice = lambda v: float(f"{MARGIN * v:.2g}") or 1e-12  # noqa: E731
    return SpecLimits.from_dict(
        {
            "parameters": {n: nice(v) for n, v in params.items()},
            "temperature_coefficients": {n: nice(v) for n, v in slopes.items()},
            "excess": EXCESS_LIMIT,
        }
    )


def _verdict(figures: dict, limits) -> dict:
    """End of line for one unit's calibration (or its failure) against ``limits``."""
    from gyrocal.fleet.eol import judge

    if "cal" not in figures:
        v = judge(RuntimeError(figures.get("failed", "calibration failed")), None, None, limits)
        return {"passed": v.passed, "failed_checks": ["calibration"], "reasons": list(v.reasons)}
    v = judge(figures["cal"], figures.get("summary"), figures.get("info"), limits)
    return {
        "passed": v.passed,
        "reasons": list(v.reasons),
        "failed_checks": sorted(k for k, c in v.checked.items() if not c["passed"]),
    }


def _fixed_settings(settings, offer):
    from dataclasses import replace

    from gyrocal.diagnosis import extended
    from gyrocal.pipeline.config import ModelSettings

    if offer.get("model"):  # a whole model of another kind (continuous_instead)
        return replace(settings, model=ModelSettings.from_dict(offer["model"]))
    for term in (offer["term"], *offer.get("together", [])):
        settings = extended(settings, term)
    return settings


def fix_text(offer) -> str:
    terms = " + ".join((offer["term"], *offer.get("together", [])))
    if offer.get("model"):
        terms = f"{offer['model'].get('kind')} model with {terms}"
    return terms


def _unit_figures(seg, settings, gyrocal_protocol: str, device: str) -> dict:
    """One unit's calibration with ``settings``: its parameters, held-out excess and what the
    file records of added terms (and, for the verdicts, the calibration, its validation and
    the segmentation's info); failed: the message."""
    from gyrocal.calibration.parameters import parameters_at
    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.chain import calibrate_observations, validation

    obs = seg.observations
    try:
        cal, fitted = calibrate_observations(
            obs,
            settings,
            meta={"device": device, "protocol": gyrocal_protocol},
            noise=seg.info.get("noise"),
            checks=False,
        )
    except GyrocalError as exc:
        return {"failed": "calibration: " + " ".join(str(exc).split())}
    p = parameters_at(cal)
    out = {
        "params": {r.parameter: (float(r.value), float(r.stderr)) for r in p.itertuples()},
        "terms": [t.spec_string() for t in cal.model.terms],
        "added_terms": cal.extra.get("added_terms"),
        "warnings": cal.extra.get("warnings"),
        "cal": cal,
        "info": seg.info,
    }
    try:
        summary = validation(obs, cal, fitted, settings).summary
        out.update(
            validation_rms=float(summary["validation_rms"]),
            noise_floor=float(summary["noise_floor"]),
            excess=float(summary["validation_rms"]) / float(summary["noise_floor"]),
            summary=summary,
        )
    except GyrocalError as exc:  # calibrated, but its validation cannot be made: judged without
        out["failed"] = "validation: " + " ".join(str(exc).split())
        out["summary"] = exc
    return out


def _compare(without: dict, with_: dict, limits=None) -> dict:
    """With vs without the fix on one unit (end of line against ``limits``)."""
    out: dict = {"failed_without": without.get("failed"), "failed_with": with_.get("failed")}
    if limits is not None:
        a, b = _verdict(without, limits), _verdict(with_, limits)
        out["eol_without"], out["eol_with"] = a["passed"], b["passed"]
        out["eol_changed"] = a["passed"] != b["passed"]
        out["eol_checks_differ"] = sorted(set(a["failed_checks"]) ^ set(b["failed_checks"]))
        out["eol_reasons_differ"] = sorted(set(a["reasons"]) ^ set(b["reasons"]))
        out["eol_failed_without"] = a["failed_checks"]
    if "excess" in without and "excess" in with_:
        out["excess_without"], out["excess_with"] = without["excess"], with_["excess"]
    if "params" not in without or "params" not in with_:
        return out
    params = []
    for name, (v0, s0) in without["params"].items():
        if name not in with_["params"]:
            continue
        v1, s1 = with_["params"][name]
        d = v1 - v0
        z0 = d / s0 if s0 > 0 else math.inf if d else 0.0
        z1 = d / s1 if s1 > 0 else math.inf if d else 0.0
        floored = s1 * s1 - s0 * s0 <= TINY * s1 * s1
        zh = d / math.sqrt(max(s1 * s1 - s0 * s0, TINY * s1 * s1)) if s1 > 0 else math.inf if d else 0.0
        params.append(
            {
                "parameter": name,
                "delta": d,
                "stderr_without": s0,
                "stderr_with": s1,
                "z_without": z0,
                "z_with": z1,
                "z_hausman": zh,
                "hausman_floored": floored,
            }
        )
    out["params"] = params
    top = max(
        params,
        key=lambda r: r["stderr_with"] / r["stderr_without"] if r["stderr_without"] > 0 else 0,
        default=None,
    )
    out["max_inflation"] = (
        (top["stderr_with"] / top["stderr_without"], top["parameter"])
        if top and top["stderr_without"] > 0
        else (None, None)
    )
    for kind in ("z_without", "z_with", "z_hausman"):
        top = max(params, key=lambda r: abs(r[kind]), default=None)
        out[f"max_{kind}"] = (abs(top[kind]), top["parameter"]) if top else (0.0, None)
    # The Hausman figure where the fix's extra freedom widened the error (where it did not,
    # its denominator is the floor and the figure says nothing).
    grew = [r for r in params if not r["hausman_floored"]]
    top = max(grew, key=lambda r: abs(r["z_hausman"]), default=None)
    out["max_z_hausman_grew"] = (abs(top["z_hausman"]), top["parameter"]) if top else (0.0, None)
    out["hausman_floored"] = len(params) - len(grew)
    for k in SIGMAS:
        out[f"beyond_{k}"] = any(abs(r["z_with"]) > k for r in params)
    added = with_.get("added_terms")
    out["added_terms"] = added
    out["kept"] = None if added is None else all(a.get("kept", True) for a in added)
    out["warnings_with"] = with_.get("warnings")
    return out


def _write_and_segment(
    protocol,
    effect,
    noise,
    seed,
    unit_overrides,
    session,
    session_overrides,
    session_seed,
    settings,
    gyrocal_protocol,
    folder,
):
    from benchmarks.zoo.generator import make_unit, write_session
    from gyrocal.pipeline.chain import segment_log

    unit = make_unit(effect=effect, protocol=protocol, noise=noise, seed=seed, **unit_overrides)
    path = Path(folder) / f"{os.getpid()}-{effect}-{protocol}-{noise}-{seed}-s{session}.parquet"
    write_session(
        unit, path, session=session, seed=session_seed, **_session_args(protocol, session, session_overrides)
    )
    try:
        return segment_log(path, settings, gyrocal_protocol)
    finally:
        path.unlink(missing_ok=True)


def _batch(case, n_others: int, settings, gyrocal_protocol: str, folder) -> list:
    """The others of ``case``'s batch: (seed, segmentation, figures with default settings),
    made once per worker for each protocol and its overrides."""
    unit_overrides, per_session = _overrides(case)
    key = (
        case[1],
        json.dumps(unit_overrides, sort_keys=True),
        json.dumps(per_session[0], sort_keys=True),
        n_others,
    )
    if key not in _BATCHES:
        units = []
        for seed in range(FIRST_OTHER_SEED, FIRST_OTHER_SEED + n_others):
            seg = _write_and_segment(
                case[1],
                "none",
                "white",
                seed,
                unit_overrides,
                0,
                per_session[0],
                1000 * seed,
                settings,
                gyrocal_protocol,
                folder,
            )
            units.append((seed, seg, _unit_figures(seg, settings, gyrocal_protocol, f"other-{seed}")))
        _BATCHES[key] = units
    return _BATCHES[key]


def run_case(case, n_others: int, folder: str) -> dict:
    from gyrocal.diagnosis import diagnose
    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.config import Settings

    started = time.perf_counter()
    effect, protocol, noise = case[:3]
    gyrocal_protocol = _gyrocal_protocol(protocol)
    settings = Settings().for_protocol(gyrocal_protocol)  # what the diagnosis starts from
    batch = batch_settings(gyrocal_protocol)
    unit_overrides, per_session = _overrides(case)
    row = {"effect": effect, "protocol": label(case), "noise": noise, "expected": case[3]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        try:
            segs = [
                _write_and_segment(
                    protocol,
                    effect,
                    noise,
                    0,
                    unit_overrides,
                    s,
                    per_session[s],
                    s,
                    settings,
                    gyrocal_protocol,
                    folder,
                )
                for s in (0, 1)
            ]
            d = diagnose(settings, segs[0].observations, segs[1].observations).to_dict()
        except GyrocalError as exc:
            row.update(
                status="diagnosis failed",
                detail=" ".join(str(exc).split()),
                seconds=round(time.perf_counter() - started, 1),
            )
            return row
        row["diagnosis_seconds"] = round(time.perf_counter() - started, 1)
        partial = d.get("partial") or []
        offer = d["best"] or (partial[0] if partial and partial[0].get("offered") else None)
        row.update(verdict=d["verdict"], explains=d["explains_the_data"], diagnosis_excess=d["excess"])
        if offer is None:
            row.update(status="no fix offered", seconds=round(time.perf_counter() - started, 1))
            return row
        fixed = _fixed_settings(batch, offer)
        row.update(
            status="fix offered",
            fix=fix_text(offer),
            offer_kind="best" if d["best"] else "partial",
            fix_model=offer.get("model"),
            fixed_terms=list(fixed.model.term_specs()),
            fixed_kind=fixed.model.kind,
        )
        carrier = [_unit_figures(segs[0], s, gyrocal_protocol, "carrier") for s in (batch, fixed)]
        row["carrier"] = _compare(*carrier)
        row["carrier"]["terms_with"] = carrier[1].get("terms")
        others = _batch(case, n_others, batch, gyrocal_protocol, folder)
        limits = batch_limits([without for _, _, without in others])
        units = []
        for seed, seg, without in others:
            with_ = _unit_figures(seg, fixed, gyrocal_protocol, f"other-{seed}")
            units.append({"seed": seed, **_compare(without, with_, limits)})
        row["others"] = units
    row["warnings"] = sorted({f"{w.filename.rsplit('/', 1)[-1]}:{w.lineno} {w.message}" for w in caught})
    row["seconds"] = round(time.perf_counter() - started, 1)
    row["summary"] = _summarise(units, True)
    return row


def run_case_safe(case, n_others: int, folder: str) -> dict:
    """:func:`run_case`, an error other than gyrocal's kept in the row rather than ending the run."""
    started = time.perf_counter()
    try:
        return run_case(case, n_others, folder)
    except Exception as exc:  # noqa: BLE001 - one case's bug is that case's row
        return {
            "effect": case[0],
            "protocol": label(case),
            "noise": case[2],
            "expected": case[3],
            "status": "error",
            "detail": f"{type(exc).__name__}: {exc}",
            "seconds": round(time.perf_counter() - started, 1),
        }


def _summarise(units: list, eol: bool) -> dict:
    ok = [u for u in units if "params" in u]
    out = {
        "units": len(units),
        "failed_with": sum(u["failed_with"] is not None for u in units),
        "failed_without": sum(u["failed_without"] is not None for u in units),
        **{
            f"{stage}_failed_with": sum((u["failed_with"] or "").startswith(stage) for u in units)
            for stage in ("calibration", "validation")
        },
        "eol_changed": sum(bool(u.get("eol_changed")) for u in units) if eol else None,
        "eol_pass_without": sum(bool(u.get("eol_without")) for u in units) if eol else None,
        "eol_pass_with": sum(bool(u.get("eol_with")) for u in units) if eol else None,
    }
    for kind in ("z_without", "z_with", "z_hausman", "z_hausman_grew"):
        top = max(ok, key=lambda u: u[f"max_{kind}"][0], default=None)
        out[f"max_{kind}"] = (top[f"max_{kind}"][0], top[f"max_{kind}"][1], top["seed"]) if top else None
    for k in SIGMAS:
        out[f"beyond_{k}"] = sum(u[f"beyond_{k}"] for u in ok)
    valid = [u for u in units if "excess_with" in u]
    out["excess_without_max"] = max((u["excess_without"] for u in valid), default=None)
    out["excess_with_max"] = max((u["excess_with"] for u in valid), default=None)
    out["excess_ratio_max"] = max((u["excess_with"] / u["excess_without"] for u in valid), default=None)
    out["excess_grew_20pct"] = sum(u["excess_with"] > 1.2 * u["excess_without"] for u in valid)
    inflation = sorted(u["max_inflation"][0] for u in ok if u["max_inflation"][0] is not None)
    out["inflation_median"] = inflation[len(inflation) // 2] if inflation else None
    top = max(
        (u for u in ok if u["max_inflation"][0] is not None),
        key=lambda u: u["max_inflation"][0],
        default=None,
    )
    out["inflation_max"] = (*top["max_inflation"], top["seed"]) if top else None
    out["checks_flipped_units"] = sum(bool(u.get("eol_checks_differ")) for u in units) if eol else None
    records = [u["kept"] for u in ok if u.get("kept") is not None]
    out["kept"] = sum(records) if records else None
    out["dropped"] = len(records) - sum(records) if records else None
    out["checks_differ"] = sorted({c for u in units for c in u.get("eol_checks_differ", [])})
    return out


def _failures(s: dict) -> str:
    parts = [f"{n} {stage}" for stage in ("calibration", "validation") if (n := s[f"{stage}_failed_with"])]
    return ", ".join(parts)


def _short(text: str, n: int = 60) -> str:
    text = text.replace("|", "/")
    return text if len(text) <= n else text[: n - 1] + "…"


def _z(entry) -> str:
    return "—" if not entry else f"{entry[0]:.3g} ({entry[1]}, u{entry[2]})"


def markdown(rows: list, n_others: int) -> str:
    out = [
        "| effect | protocol | fix | carrier excess before → after | others: EOL verdicts changed "
        f"(of {n_others}) | others: max \\|Δ\\|/σ_with (parameter) | others beyond 1σ/2σ/3σ "
        "| fix kept on others | seconds |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["status"] != "fix offered":
            why = r["status"] + (f": {_short(r['detail'], 80)}" if r.get("detail") else "")
            out.append(
                f"| {r['effect']} | {r['protocol']} | *{why}* | — | — | — | — | — | {r['seconds']:.0f} |"
            )
            continue
        s, c = r["summary"], r["carrier"]
        carrier = (
            f"{c['excess_without']:.3g} → {c['excess_with']:.3g}"
            if "excess_with" in c
            else f"failed: {_short(c.get('failed_with') or c.get('failed_without') or '?', 40)}"
        )
        if c.get("kept") is not None:
            carrier += " (kept)" if c["kept"] else " (dropped)"
        eol = (
            "— (no spec)"
            if s["eol_changed"] is None
            else f"{s['eol_changed']} ({s['eol_pass_without']} → {s['eol_pass_with']} pass)"
        )
        if s["checks_flipped_units"]:
            eol += f"; a check flipped on {s['checks_flipped_units']}: {', '.join(s['checks_differ'])}"
        if s["failed_with"]:
            eol += f"; failed with the fix: {_failures(s)}"
        kept = "—" if s["kept"] is None else f"{s['kept']} kept, {s['dropped']} dropped"
        out.append(
            f"| {r['effect']} | {r['protocol']} | {_short(r['fix'])} | {carrier} | {eol} | "
            f"{_z(s['max_z_with'])} | {s['beyond_1']}/{s['beyond_2']}/{s['beyond_3']} | {kept} | "
            f"{r['seconds']:.0f} |"
        )
    return "\n".join(out)


def details(rows: list) -> str:
    out = [
        "| effect | protocol | max \\|Δ\\|/σ_without | max Hausman z | max Hausman z where σ grew "
        "| σ_with/σ_without, units' largest: median (max) | others' excess without → with (max; max ratio) "
        "| others whose excess grew > 1.2× |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["status"] != "fix offered":
            continue
        s = r["summary"]
        excess = (
            "—"
            if s["excess_with_max"] is None
            else f"{s['excess_without_max']:.3g} → {s['excess_with_max']:.3g}; ×{s['excess_ratio_max']:.3g}"
        )
        infl = (
            "—"
            if s["inflation_median"] is None
            else f"{s['inflation_median']:.3g}; max {_z(s['inflation_max'])}"
        )
        out.append(
            f"| {r['effect']} | {r['protocol']} | {_z(s['max_z_without'])} | {_z(s['max_z_hausman'])} | "
            f"{_z(s['max_z_hausman_grew'])} | {infl} | {excess} | {s['excess_grew_20pct']} |"
        )
    return "\n".join(out)


def totals(rows: list, n_others: int) -> str:
    offered = [r for r in rows if r["status"] == "fix offered"]
    none = [r for r in rows if r["status"] == "no fix offered"]
    failed = [r for r in rows if r["status"] in ("diagnosis failed", "error")]
    units = sum(r["summary"]["units"] for r in offered)
    lines = [
        f"cases: {len(rows)}; a fix offered {len(offered)}, no fix offered {len(none)}"
        + (f" ({', '.join(r['effect'] + ' ' + r['protocol'] for r in none)})" if none else "")
        + (f", diagnosis failed or error {len(failed)}" if failed else ""),
        f"other units judged: {units} ({len(offered)} fixes × {n_others} units)",
    ]
    if offered:
        judged_eol = [r for r in offered if r["summary"]["eol_changed"] is not None]
        lines.append(
            f"EOL verdicts changed by the fix: {sum(r['summary']['eol_changed'] for r in judged_eol)} "
            f"of {sum(r['summary']['units'] for r in judged_eol)} (in "
            f"{sum(r['summary']['eol_changed'] > 0 for r in judged_eol)} of {len(judged_eol)} cases)"
        )
        lines.append(
            f"units with an EOL check flipped by the fix: "
            f"{sum(r['summary']['checks_flipped_units'] for r in judged_eol)} of "
            f"{sum(r['summary']['units'] for r in judged_eol)}"
        )
        lines.append(
            f"units whose held-out excess grew > 1.2× with the fix: "
            f"{sum(r['summary']['excess_grew_20pct'] for r in offered)} of {units}"
        )
        lines.append(
            "failed with the fix (of the others): "
            + ", ".join(
                f"{stage} {sum(r['summary'][f'{stage}_failed_with'] for r in offered)}"
                for stage in ("calibration", "validation")
            )
        )
        for k in SIGMAS:
            n = sum(r["summary"][f"beyond_{k}"] for r in offered)
            cases = sum(r["summary"][f"beyond_{k}"] > 0 for r in offered)
            lines.append(f"units with a parameter moved beyond {k} σ_with: {n} of {units} (in {cases} cases)")
        records = [r for r in offered if r["summary"]["kept"] is not None]
        lines.append(
            "the fix kept / dropped on the others: "
            + (
                f"{sum(r['summary']['kept'] for r in records)} / {sum(r['summary']['dropped'] for r in records)}"
                if records
                else "— (the calibration files record no added_terms)"
            )
        )
    return "\n".join(f"- {line}" for line in lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--others", type=int, default=19)
    parser.add_argument("--cases", choices=("all", "smallest"), default="all")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", help="write the rows (with per-unit details) as JSON here")
    args = parser.parse_args(argv)
    from host import cores, cpu_name

    if args.cases == "all":
        cases = [c for c in CASES if judged(c)]
    else:
        warmup = next(c for c in CASES if c[0] == "warmup" and c[1] == "turntable3")
        cases = [c for c in SMALLEST if judged(c)] + ([warmup] if warmup not in SMALLEST else [])
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fix_batch-") as folder, ProcessPoolExecutor(args.jobs) as pool:
        jobs = [pool.submit(run_case_safe, case, args.others, folder) for case in cases]
        rows = [j.result() for j in jobs]
    elapsed = time.perf_counter() - started
    print(
        f"# {time.strftime('%Y-%m-%d')}, {cpu_name()}, {cores()}, {len(cases)} cases, "
        f"{args.others} others each, {args.jobs} jobs, {elapsed:.0f} s\n"
    )
    print(markdown(rows, args.others))
    print()
    print(totals(rows, args.others))
    print()
    print(details(rows))
    warned = [r for r in rows if r.get("warnings")]
    if warned:
        print(
            "\nRuntimeWarnings:"
            + "".join(f"\n- {r['effect']} {r['protocol']}: {'; '.join(r['warnings'])}" for r in warned)
        )
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {"others": args.others, "seconds": round(elapsed, 1), "rows": rows}, indent=1, default=str
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
