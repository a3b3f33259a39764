rule segment:
    input:
        log=log_input,
    output:
        obs="results/{batch}/{device}/{session}/observations.parquet",
    log:
        "logs/segment/{batch}/{device}/{session}.log",
    group:
        "unit"
    conda:
        ENV
    threads: 2
    resources:
        mem_mb=lambda wildcards, attempt: 2000 * attempt,
        runtime=lambda wildcards, attempt: 5 * attempt,
        attempt=lambda wildcards, attempt: attempt,
    params:
        guard=GUARD,
        limits=job_limits,
        args=segment_args,
        version=GYROCAL_VERSION,
    shell:
        "{params.guard} --attempt {resources.attempt} {params.limits} segment {params.args} --out $(dirname {output.obs:q}) "
        "--record-failures > {log:q} 2>&1"
