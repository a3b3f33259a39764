"""The real hand-rotation session (data/real/imucal-ferraris) through gyrocal, side by side
with imucal's own calibration of the same samples.

    python benchmarks/real_ferraris.py [--markdown]

Prints, for every scale, cross-axis and bias term: gyrocal's value with two standard
errors (the noise's alone, and with the hand's assumed errors: a 1° guide, a unit flat to
0.5°), imucal's value, their difference and the difference in units of each standard error;
then the same for gyrocal with the acceleration sensitivity added (imucal's model) and for
the phases found from the data instead of the annotation; for the session in imucal's
labelled form (its sections as a label column, rows grouped by label, the handling cut
away: tests/protocols/test_ferraris.py makes it), imported with a map alone, from its labels and from
the data alone; then every turn's integrated angle, raw and after each compensation (a full
turn reads 360°)."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gyrocal.calibration.apply import apply_calibration  # noqa: E402
from gyrocal.importer import import_log  # noqa: E402
from gyrocal.pipeline.chain import run  # noqa: E402
from gyrocal.pipeline.config import Settings  # noqa: E402
from tests.protocols.test_ferraris import LABELLED_MAP, labelled_session  # noqa: E402

REAL = ROOT / "data" / "real" / "imucal-ferraris"
RATE = 102.4
G = 9.81  # imucal's gravity, m/s²
TERMS = [
    ("scale.x", (0, 0)),
    ("scale.y", (1, 1)),
    ("scale.z", (2, 2)),
    ("misalignment.x.y", (0, 1)),
    ("misalignment.x.z", (0, 2)),
    ("misalignment.y.x", (1, 0)),
    ("misalignment.y.z", (1, 2)),
    ("misalignment.z.x", (2, 0)),
    ("misalignment.z.y", (2, 1)),
]


def imucal_reference():
    from imucal import FerrarisCalibration, ferraris_regions_from_section_list

    data = pd.read_csv(REAL / "session.csv").set_index("n_samples")
    sections = pd.DataFrame(json.loads((REAL / "sections.json").read_text())).T
    regions = ferraris_regions_from_section_list(data, sections)
    info = FerrarisCalibration(grav=G).compute(
        regions, sampling_rate_hz=RATE, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
    )
    acc, gyr = data[["acc_x", "acc_y", "acc_z"]].to_numpy(), data[["gyr_x", "gyr_y", "gyr_z"]].to_numpy()
    _, compensated = info.calibrate(acc, gyr, "m/s^2", "deg/s")
    return info, compensated


def settings(hand: bool, terms=None) -> Settings:
    options = {} if hand else {"angle_uncertainty_deg": 0.0, "tilt_uncertainty_deg": 0.0}
    section = {"options": options}
    if terms:
        section["model"] = {"terms": terms}
    return Settings.from_dict({"protocols": {"ferraris": section}}).for_protocol("ferraris")


def terms_of(cal):
    values = dict(zip(cal.grid.names, cal.grid.values[0], strict=False))
    stderr = dict(zip(cal.grid.names, cal.grid.stderr[0], strict=False))
    return values, stderr


def comparison(log, ref, *, terms=None) -> pd.DataFrame:
    noise = run(log, settings(False, terms), protocol="ferraris").calibration
    stated = run(log, settings(True, terms), protocol="ferraris").calibration
    values, se_noise = terms_of(noise)
    _, se_stated = terms_of(stated)
    K_ref = ref.K_g @ ref.R_g
    rows = []
    for name, (i, j) in TERMS:
        theirs = K_ref[i, j] - (1.0 if i == j else 0.0)
        rows.append((name, values[name], se_noise[name], se_stated[name], theirs))
    for k, a in enumerate("xyz"):
        rows.append(
            (f"bias.{a}", values[f"bias.{a}"], se_noise[f"bias.{a}"], se_stated[f"bias.{a}"], ref.b_g[k])
        )
    if terms:
        for a, axis in enumerate("xyz"):
            for b, other in enumerate("xyz"):
                name = f"g_sensitivity.{axis}.{other}"
                rows.append((name, values[name], se_noise[name], se_stated[name], ref.K_ga[a, b] * G))
    out = pd.DataFrame(rows, columns=["term", "gyrocal", "se_noise", "se_stated", "imucal"])
    out["difference"] = out["gyrocal"] - out["imucal"]
    out["diff/se_noise"] = out["difference"] / out["se_noise"]
    out["diff/se_stated"] = out["difference"] / out["se_stated"]
    return out


def turn_angles(log, compensated_imucal, tmp: Path) -> pd.DataFrame:
    cal = run(log, settings(True), protocol="ferraris").calibration
    out = tmp / "compensated.parquet"
    apply_calibration(cal, log, out)
    raw = pd.read_parquet(log)
    ours = pd.read_parquet(out)
    sections = json.loads((REAL / "sections.json").read_text())
    rows = []
    for k, axis in enumerate("xyz"):
        s = sections[f"{axis}_rot"]
        rows_ = slice(s["start"], s["end"])
        rows.append(
            {
                "turn": f"{axis}_rot",
                "raw_deg": raw[f"gyro_{axis}"].iloc[rows_].sum() / RATE,
                "gyrocal_deg": ours[f"gyro_{axis}"].iloc[rows_].sum() / RATE,
                "imucal_deg": compensated_imucal[rows_, k].sum() / RATE,
            }
        )
    table = pd.DataFrame(rows)
    for c in ("raw", "gyrocal", "imucal"):
        table[f"{c}_error_deg"] = table[f"{c}_deg"].abs() - 360.0
    return table


def markdown(df: pd.DataFrame) -> str:
    cell = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(df.columns) + " |", "|" + "---|" * len(df.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--markdown", action="store_true", help="print Markdown tables")
    args = ap.parse_args(argv)
    show = (
        markdown
        if args.markdown
        else (lambda df: df.to_string(index=False, float_format=lambda v: f"{v:.6g}"))
    )
    ref, compensated = imucal_reference()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        annotated, plain = tmp / "annotated.parquet", tmp / "plain.parquet"
        import_log(REAL / "session.csv", annotated, REAL / "import.yaml")
        text = "\n".join(
            line
            for line in (REAL / "import.yaml").read_text().splitlines()
            if not line.startswith("sections")
        )
        (tmp / "plain.yaml").write_text(text)
        import_log(REAL / "session.csv", plain, tmp / "plain.yaml")
        labelled, cut = tmp / "labelled.parquet", tmp / "cut.parquet"
        (tmp / "labelled.yaml").write_text(LABELLED_MAP)
        import_log(labelled_session(tmp), labelled, tmp / "labelled.yaml")
        (tmp / "cut.yaml").write_text(
            "\n".join(line for line in LABELLED_MAP.splitlines() if "part" not in line)
        )
        import_log(labelled_session(tmp, label=False), cut, tmp / "cut.yaml")
        for title, log, terms in [
            ("annotated sections, default model (12 parameters)", annotated, None),
            (
                "annotated sections, + g_sensitivity (imucal's model)",
                annotated,
                ["bias", "scale", "misalignment", "g_sensitivity"],
            ),
            ("phases found from the data, default model", plain, None),
            ("imucal's labelled form, from its label column, default model", labelled, None),
            (
                "imucal's labelled form without its labels: cut to its sections, phases "
                "found from the data, default model",
                cut,
                None,
            ),
        ]:
            print(f"\n## {title}\n")
            print(show(comparison(log, ref, terms=terms)))
        print("\n## every turn's angle, integrated over its annotated section\n")
        print(show(turn_angles(annotated, compensated, tmp)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
