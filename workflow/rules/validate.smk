rule validate:
    input:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        terms=TERM_FILES,
        cal="results/{batch}/{device}/{session}/calibration.json",
    output:
        validation="results/{batch}/{device}/{session}/validation.json",
        holds="results/{batch}/{device}/{session}/validation_holds.parquet",
        table_hold_means="results/{batch}/{device}/{session}/table_hold_means.parquet",
        table_samples="results/{batch}/{device}/{session}/table_samples.parquet",
        by_temperature="results/{batch}/{device}/{session}/by_temperature.parquet",
    log:
        "logs/validate/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/validate/{batch}/{device}/{session}.tsv"
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
        settings=settings_json(MODEL, "validate"),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} validate $(dirname {input.obs:q}) {params.unit} "
        "--settings-json {params.settings:q} --record-failures > {log:q} 2>&1"
