"""One unit judged as a benchmark sees it: the diagnosis' answer in coarse words, and what the
fix it offers does to a session it never saw.

The interface between gyrocal and generators written without reading it (the sealed set in
``benchmarks/sealed``): a generator writes three sessions of one unit and calls
:func:`judge_unit`; it scores the answer against its own truth.

    judge_unit([s0, s1, s2], protocol="turntable", one_session=False) -> dict

Session 0 is diagnosed (with session 1 as the other session unless ``one_session``); the fix
offered is calibrated on session 0 and judged on session 2. The result:

- ``verdict``: ``quiet`` (the model explains the data; also from one log whose excess lies
  within the slow wander its static data cannot rule out, which the diagnosis leaves to
  another session; ``reason`` ``turn-on bias`` where the other session misses by the
  offsets of its power-ons alone, which no calibration carries), ``fix`` (a term offered),
  ``no_sensor_term`` (no term can carry the excess; ``reason`` says why) or ``error``;
- ``reads``: the coarse kinds of input the offered fix reads, from ``rate``, ``accel``,
  ``temperature``, ``thermal`` (the temperature's rate, lag, or direction of travel),
  ``time``, ``mount``;
- ``acts_on``: ``bias``, ``scale`` or ``cross-axis`` (None without a fix);
- ``reason``: for ``no_sensor_term``: ``mounting``, ``lab``, ``unit changed``,
  ``between points``, ``slow noise``, ``too small``, ``direction of approach`` (the other
  session fails only where the temperature came from the other side: ``reads`` is then
  ``thermal``) or ``unexplained``;
- ``next_before_rms``, ``next_after_rms``: the hold-mean RMS error (deg/s) on session 2 of
  the default calibration of session 0, and of the calibration with the fix;
- ``peer_next_after_rms``: the same for the sparse-regression peer (``peer_sparse.py``),
  None where it is not available;
- ``floor``: gyrocal's hold-mean noise floor on session 2 (deg/s);
- ``detail``: the verdict's text and the term, for whoever may read per-unit rows.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

# The reason a verdict gives where no term is offered, in the benchmark's words.
REASONS = {
    "the mounting": "mounting",
    "fixed in the lab": "lab",
    "between temperature points": "between points",
    "too small": "too small",
    "does not carry over": "unit changed",
    "slow noise": "slow noise",
}


def _acts_on(term: str) -> str:
    """Where a term acts: on the other axes' outputs, on the scale (its own rate times a
    function, or any odd function of the own rate alone), or on the bias."""
    from gyrocal.terms import make_term

    made = make_term(term)
    inner = getattr(made, "term", made)
    formula = getattr(inner, "formula", "").replace(" ", "")
    if inner.name.startswith("cross") or inner.name.startswith("misalign"):
        return "cross-axis"
    scaled = formula.startswith("rate_own*") or formula.endswith("*rate_own") or formula.startswith("{x}*")
    if inner.name.startswith("scale") or getattr(inner, "by", None) == "rate_own" or scaled:
        return "scale"
    from gyrocal.diagnosis.shapes import odd_in_own_rate

    return "scale" if odd_in_own_rate(made) else "bias"


def _answer(d: dict[str, Any]) -> dict[str, Any]:
    partial = d.get("partial") or []
    offer = d["best"] or (partial[0] if partial and partial[0].get("offered") else None)
    if offer:
        terms = [offer["term"], *offer.get("together", [])]
        from gyrocal.diagnosis.verdict import term_reads  # gyrocal's kinds are the coarse words

        reads = sorted(set().union(*(term_reads(t) for t in terms)))
        return {"verdict": "fix", "reads": reads, "acts_on": _acts_on(offer["term"]), "reason": None}
    why = d.get("unexplained") or {}
    approach = d.get("approach") or {}
    if approach.get("explains"):
        # the other session fails where the temperature came from the other side: a
        # hysteresis no term of one session can carry
        return {
            "verdict": "no_sensor_term",
            "reads": ["thermal"],
            "acts_on": None,
            "reason": "direction of approach",
        }
    nxt = d.get("next_session") or {}
    if (
        d["explains_the_data"]
        and not why
        and d["best"] is None
        and d.get("unrepeated")
        and nxt.get("fails_in_practice")
    ):
        # the excess's pattern does not come back in the other session, where the calibration
        # fails: the verdict calls it slow noise the static data did not resolve, not a change
        # of the unit (where the calibration carries over, it says nothing is missing: quiet)
        return {"verdict": "no_sensor_term", "reads": [], "acts_on": None, "reason": "slow noise"}
    if (
        d["explains_the_data"]
        and not why
        and d["best"] is None
        and (d.get("floors_differ") or {}).get("covers_other")
    ):
        # the other session fails within what this session's own, larger noise leaves: the
        # verdict calls it slow noise this session's static data caught, not a unit change
        return {"verdict": "no_sensor_term", "reads": [], "acts_on": None, "reason": "slow noise"}
    if d["explains_the_data"] and not why and d["best"] is None and nxt and nxt.get("fails_in_practice"):
        return {"verdict": "no_sensor_term", "reads": [], "acts_on": None, "reason": "unit changed"}
    if d["explains_the_data"] and not why:
        # One log whose excess lies within the slow wander its static data cannot rule out is
        # told "explains the data as far as one session can tell", another session to tell
        # wander from an effect: the verdict names nothing missing, so the answer is quiet.
        # Where the other session misses by its power-ons' offsets alone, which no
        # calibration carries, the answer is quiet and says so.
        power_on = bool(nxt) and _power_ons_alone(nxt)
        return {
            "verdict": "quiet",
            "reads": [],
            "acts_on": None,
            "reason": "turn-on bias" if power_on else None,
        }
    reason = REASONS.get(why.get("reason"), "unexplained")
    return {"verdict": "no_sensor_term", "reads": [], "acts_on": None, "reason": reason}


def _power_ons_alone(nxt: dict[str, Any]) -> bool:
    """The other session missing by its power-ons' offsets alone (gyrocal's
    ``sessions.power_ons_alone``)."""
    from gyrocal.diagnosis.sessions import power_ons_alone

    return "error" not in nxt and power_ons_alone(nxt)


def judge_unit(
    logs: list, protocol: str, one_session: bool = False, *, peer: bool = True, keep_diagnosis: bool = False
) -> dict[str, Any]:
    """Diagnose session 0 (with session 1 unless ``one_session``), judge the fix on session 2;
    the sparse peer beside it unless not ``peer``; with ``keep_diagnosis``, the diagnosis'
    JSON as ``diagnosis`` (a test reads both)."""
    from dataclasses import replace

    from gyrocal.diagnosis import diagnose, extended
    from gyrocal.fleet.drift import revalidate
    from gyrocal.io.errors import GyrocalError
    from gyrocal.pipeline.chain import run, segment_log
    from gyrocal.pipeline.config import ModelSettings, Settings

    s0, s1, s2 = (Path(p) for p in logs)
    settings = Settings().for_protocol(protocol)
    out: dict[str, Any] = {"peer_next_after_rms": None}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            obs = segment_log(s0, settings, protocol).observations
            other = None if one_session else segment_log(s1, settings, protocol).observations
            d = diagnose(settings, obs, other).to_dict()
            out.update(_answer(d))
            out["detail"] = d["verdict"]
            if keep_diagnosis:
                out["diagnosis"] = d
            unseen = segment_log(s2, settings, protocol).observations

            def next_rms(s: Settings) -> tuple[float, float]:
                r = revalidate(run(s0, s, protocol=protocol).calibration, unseen)
                return float(r["validation_rms"]), float(r["noise_floor"])

            before, floor = next_rms(settings)
            out.update(next_before_rms=before, next_after_rms=before, floor=floor)
            if out["verdict"] == "fix":
                partial = d.get("partial") or []
                offer = d["best"] or partial[0]
                fixed = settings
                for term in (offer["term"], *offer.get("together", [])):
                    fixed = extended(fixed, term)
                if offer.get("model"):
                    fixed = replace(settings, model=ModelSettings.from_dict(offer["model"]))
                out["next_after_rms"] = next_rms(fixed)[0]
                out["detail"] += f" [{offer['term']}]"
    except GyrocalError as exc:
        return {**out, "verdict": "error", "reads": [], "acts_on": None, "reason": None, "detail": str(exc)}
    if not peer:
        return out
    try:
        from peer_sparse import peer_next
    except ImportError:
        return out
    with contextlib.suppress(GyrocalError):  # the peer's own failure leaves its figure None
        out["peer_next_after_rms"] = float(peer_next(s0, s2, protocol)["next_after_rms"])
    return out
