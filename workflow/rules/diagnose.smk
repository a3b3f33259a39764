rule diagnose:
    input:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        terms=TERM_FILES,
    output:
        diagnosis="results/{batch}/{device}/{session}/diagnosis.json",
        residuals="results/{batch}/{device}/{session}/residuals.parquet",
    log:
        "logs/diagnose/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/diagnose/{batch}/{device}/{session}.tsv"
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
        settings=settings_json(DIAGNOSIS, "diagnose"),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} diagnose --unit $(dirname {input.obs:q}) -o {output.diagnosis:q} "
        "--residuals {output.residuals:q} {params.unit} --settings-json {params.settings:q} "
        "--record-failures > {log:q} 2>&1"
