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
    log:
        "logs/fleet.log",
    benchmark:
        "results/benchmark/fleet.tsv"
    conda:
        ENV
    params:
        gyrocal=GYROCAL,
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} fleet --manifest {input.manifest:q} --results results --reports reports "
        "-o {output.index:q} --bundle {output.bundle:q} > {log:q} 2>&1"
