rule report:
    # The unit's products; the tables beside them come from the same jobs
    # (workflow/rules/analyse.smk).
    input:
        cal="results/{batch}/{device}/{session}/calibration.json",
        validation="results/{batch}/{device}/{session}/validation.json",
        diagnosis="results/{batch}/{device}/{session}/diagnosis.json",
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
        attempt=lambda wildcards, attempt: attempt,
    params:
        guard=GUARD,
        limits=job_limits,
        args=stage_args(
            {k: config[k] for k in ("segmentation", "model", "diagnosis")}, "report"
        ),
        version=GYROCAL_VERSION,
    shell:
        "{params.guard} --attempt {resources.attempt} {params.limits} report $(dirname {input.cal:q}) -o {output:q} {params.args} "
        "--record-failures > {log:q} 2>&1"
