# The fleet summary. The unit reports also go into one folder registered with the
# report, so `snakemake --report report.zip` bundles them without a caption per unit.


rule fleet:
    input:
        manifest=config["devices"],
        calibrations=unit_files("calibration.json"),
        validations=unit_files("validation.json"),
        diagnoses=unit_files("diagnosis.json"),
        reports=unit_reports(),
    output:
        index=report(
            "reports/index.html",
            caption="../report/fleet.rst",
            category="Fleet",
        ),
        bundle=report(
            directory("results/report_bundle"),
            htmlindex="index.html",
            caption="../report/units.rst",
            category="Units",
        ),
        eol="results/eol.json",
        drift=[f"reports/drift/{device}.html" for device in DRIFT_DEVICES],
    log:
        "logs/fleet.log",
    benchmark:
        "results/benchmark/fleet.tsv"
    conda:
        ENV
    threads: 1
    resources:
        mem_mb=lambda wildcards, attempt: 2000 * attempt,
        runtime=lambda wildcards, attempt: 30 * attempt,
    params:
        gyrocal=GYROCAL,
        settings=json.dumps(
            {k: config.get(k, {}) for k in ("spec", "outliers", "drift")},
            sort_keys=True,
        ),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} fleet --manifest {input.manifest:q} --results results --reports reports "
        "-o {output.index:q} --bundle {output.bundle:q} --settings-json {params.settings:q} "
        "--eol {output.eol:q} > {log:q} 2>&1"
