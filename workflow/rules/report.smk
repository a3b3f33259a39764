rule report:
    # What the analyse job writes: it runs after the unit's segmentation, so these are
    # newer than every file the report reads, and one set of inputs re-runs it for any.
    input:
        cal="results/{batch}/{device}/{session}/calibration.json",
        validation="results/{batch}/{device}/{session}/validation.json",
        holds="results/{batch}/{device}/{session}/validation_holds.parquet",
        table_hold_means="results/{batch}/{device}/{session}/table_hold_means.parquet",
        table_samples="results/{batch}/{device}/{session}/table_samples.parquet",
        by_temperature="results/{batch}/{device}/{session}/by_temperature.parquet",
        diagnosis="results/{batch}/{device}/{session}/diagnosis.json",
        residuals="results/{batch}/{device}/{session}/residuals.parquet",
        terms=TERM_FILES,
    output:
        "reports/{batch}/{device}/{session}.html",
    log:
        "logs/report/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/report/{batch}/{device}/{session}.tsv"
    group:
        "unit"
    conda:
        ENV
    threads: 1
    resources:
        mem_mb=lambda wildcards, attempt: 1000 * attempt,
        runtime=lambda wildcards, attempt: 5 * attempt,
    params:
        gyrocal=GYROCAL,
        unit=unit_args,
        settings=settings_json(
            {k: config[k] for k in ("segmentation", "model", "diagnosis")}, "report"
        ),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} report $(dirname {input.cal:q}) -o {output:q} {params.unit} "
        "--settings-json {params.settings:q} --record-failures > {log:q} 2>&1"
