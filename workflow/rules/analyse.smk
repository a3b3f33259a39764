# Fit, validate and diagnose a unit in one job (`gyrocal analyse`): three steps of seconds
# that always run together. One job instead of three is a third of the jobs Snakemake
# plans per unit (docs/cluster.md) and two Python start-ups fewer; each step still writes
# its own outputs and failure records (gyrocal/stages.py analyse_stage).


rule analyse:
    input:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        terms=TERM_FILES,
    output:
        cal="results/{batch}/{device}/{session}/calibration.json",
        validation="results/{batch}/{device}/{session}/validation.json",
        holds="results/{batch}/{device}/{session}/validation_holds.parquet",
        table_hold_means="results/{batch}/{device}/{session}/table_hold_means.parquet",
        table_samples="results/{batch}/{device}/{session}/table_samples.parquet",
        by_temperature="results/{batch}/{device}/{session}/by_temperature.parquet",
        diagnosis="results/{batch}/{device}/{session}/diagnosis.json",
        residuals="results/{batch}/{device}/{session}/residuals.parquet",
    log:
        "logs/analyse/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/analyse/{batch}/{device}/{session}.tsv"
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
        settings=settings_json(ANALYSIS, "analyse"),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} analyse $(dirname {input.obs:q}) {params.unit} "
        "--settings-json {params.settings:q} --record-failures > {log:q} 2>&1"
