rule fit:
    input:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        terms=TERM_FILES,
    output:
        cal="results/{batch}/{device}/{session}/calibration.json",
    log:
        "logs/fit/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/fit/{batch}/{device}/{session}.tsv"
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
        settings=settings_json(MODEL, "fit"),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} fit $(dirname {input.obs:q}) {params.unit} --settings-json {params.settings:q} "
        "--record-failures > {log:q} 2>&1"
