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
    # From the jobs' own records (benchmarks/requests.py, docs/cluster.md): a full-protocol
    # log keeps 1.35 cores busy at 793 MiB for 5 s; a second core would sit idle most of
    # the job. A retry doubles memory and time.
    threads: 1
    resources:
        mem_mb=lambda wildcards, attempt: 1200 * attempt,
        runtime=lambda wildcards, attempt: 2 * attempt,
        attempt=lambda wildcards, attempt: attempt,
    params:
        guard=GUARD,
        limits=job_limits,
        args=segment_args,
        version=GYROCAL_VERSION,
    shell:
        "{params.guard} --attempt {resources.attempt} {params.limits} segment {params.args} --out $(dirname {output.obs:q}) "
        "--record-failures > {log:q} 2>&1"
