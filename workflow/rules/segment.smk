rule segment:
    input:
        log=log_input,
    output:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        segments="results/{batch}/{device}/{session}/segments.parquet",
        timeline="results/{batch}/{device}/{session}/timeline.parquet",
    log:
        "logs/segment/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/segment/{batch}/{device}/{session}.tsv"
    group:
        "unit"
    conda:
        ENV
    threads: 2
    resources:
        mem_mb=lambda wildcards, attempt: 2000 * attempt,
        runtime=lambda wildcards, attempt: 5 * attempt,
    params:
        gyrocal=GYROCAL,
        # Snakemake's local copy of a log in storage; the manifest's path otherwise (a
        # missing log has no input: the stage records it).
        log=lambda wildcards, input: input.log or unit(wildcards)["log"],
        unit=unit_args,
        settings=settings_json(SEGMENTATION, "segment"),
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} segment {params.log:q} --out $(dirname {output.obs:q}) {params.unit} "
        "--settings-json {params.settings:q} --record-failures > {log:q} 2>&1"
