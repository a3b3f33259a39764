# Fit, validate, diagnose and report a unit in one job (`gyrocal analyse --report`): four
# steps of seconds that always run together, sharing one fit of the configured model and
# one Python start-up. One job instead of four is fewer jobs for Snakemake to plan per unit
# (docs/cluster.md), and one job log and one benchmark record per unit session fewer; each
# step still writes its own outputs and failure records (gyrocal/run/stages.py
# analyse_stage; a failed step's record reaches the report, which says what failed).
#
# The rules declare the files another job reads: here the calibration, validation,
# diagnosis and report, which the fleet summary reads. The files only the report reads
# (validation_holds, table_hold_means, table_samples, by_temperature, residuals,
# protocol.json; the segmentation's segments and timeline) are written beside them by the
# same job, every time, and are not declared: each declared file costs Snakemake work per
# unit as it plans (docs/cluster.md), and declaring them would not rebuild one deleted by hand
# either (Snakemake leaves a missing intermediate file alone while what was made from it
# is up to date). `gyrocal report` rendered after one was deleted names it.


rule analyse:
    input:
        obs="results/{batch}/{device}/{session}/observations.parquet",
        other=other_observations,
        terms=TERM_FILES,
    output:
        cal="results/{batch}/{device}/{session}/calibration.json",
        validation="results/{batch}/{device}/{session}/validation.json",
        diagnosis="results/{batch}/{device}/{session}/diagnosis.json",
        report="reports/{batch}/{device}/{session}.html",
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
        attempt=lambda wildcards, attempt: attempt,
    params:
        guard=GUARD,
        limits=job_limits,
        # the report's reproduce command names the segmentation's settings too
        args=stage_args(
            {k: config[k] for k in ("segmentation", "model", "diagnosis")}, "report"
        ),
        other=other_session_option,
        version=GYROCAL_VERSION,
    shell:
        "{params.guard} --attempt {resources.attempt} {params.limits} analyse $(dirname {input.obs:q}) {params.args} {params.other} "
        "--report {output.report:q} --record-failures > {log:q} 2>&1"
