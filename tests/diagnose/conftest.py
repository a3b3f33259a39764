"""The shared helpers of tests/conftest.py that this folder's tests import as ``.conftest``,
and sessions of the independent zoo's units (benchmarks/zoo) judged as a user meets them."""

from ..conftest import make_log  # noqa: F401


def zoo_sessions(tmp_path, effect, seed, rate_hz=10.0, sessions=None, *, with_info=False, **unit_overrides):
    """Three sessions of one zoo unit on the three-mount turntable; ``sessions`` maps a
    session to its protocol overrides (a visit order of its own). ``with_info``: with the
    generator's truth of each session too."""
    from benchmarks.zoo.generator import make_unit, write_session

    tmp_path.mkdir(parents=True, exist_ok=True)
    unit = make_unit(effect=effect, protocol="turntable3", noise="white", seed=seed, **unit_overrides)
    logs = [tmp_path / f"{effect}-s{s}.parquet" for s in range(3)]
    infos = [
        write_session(
            unit, log, session=s, seed=1000 * seed + s, rate_hz=rate_hz, **(sessions or {}).get(s, {})
        )
        for s, log in enumerate(logs)
    ]
    return (logs, infos) if with_info else logs


def next_session(logs, settings, offer: dict | None) -> float:
    """Session 0 calibrated (with the offer's terms, or in the offer's model), judged on
    session 2: its hold-mean RMS ÷ the floor."""
    from dataclasses import replace

    from gyrocal.diagnosis import extended
    from gyrocal.fleet.drift import revalidate
    from gyrocal.pipeline.chain import run, segment_log
    from gyrocal.pipeline.config import ModelSettings

    if offer is not None:
        for term in (offer["term"], *offer.get("together", [])):
            settings = extended(settings, term)
        if offer.get("model"):
            settings = replace(settings, model=ModelSettings.from_dict(offer["model"]))
    cal = run(logs[0], settings).calibration
    r = revalidate(cal, segment_log(logs[2], settings).observations)
    return r["validation_rms"] / r["noise_floor"]
