# The fleet summary. The unit reports also go into one folder registered with the
# report, so `snakemake --report report.zip` bundles them without a caption per unit.
# It reads each unit's calibration, validation and diagnosis too, but declares only the
# unit reports: each report depends on those files and is rewritten whenever one of
# them changes, so the summary re-runs all the same, and planning a fleet resolves one
# file per unit here instead of four (docs/cluster.md).


rule fleet:
    input:
        manifest=config["devices"],
        reports=unit_reports(),
        # the earlier sessions the drift pages take from the registry (common.smk)
        history=f"results/{HISTORY_NAME}",
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
        table="results/fleet.parquet",
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
        # the registry the run's calibrations are indexed in (config registry:), not an
        # output: it outlives the run, and Snakemake would remove an output before the job
        registry=(
            "--registry " + shlex.quote(str(config["registry"]))
            if "registry" in config
            else ""
        ),
    shell:
        "{params.gyrocal} fleet --manifest {input.manifest:q} --results results --reports reports "
        "-o {output.index:q} --bundle {output.bundle:q} --settings-json {params.settings:q} "
        "--eol {output.eol:q} --table {output.table:q} --history {input.history:q} {params.registry} "
        "> {log:q} 2>&1"
