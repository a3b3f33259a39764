# Fit, validate, diagnose and report a unit in one job (`gyrocal analyse --report`): four
# steps of seconds that always run together, sharing one fit of the configured model and
# one Python start-up. One job instead of four is fewer jobs for Snakemake to plan per unit
# (docs/cluster.md), and one job log per unit session instead of four; each step still
# writes its own outputs and failure records (gyrocal/run/stages.py analyse_stage; a failed
# step's record reaches the report, which says what failed).
#
# A unit session leaves four files (docs/cluster.md), and Snakemake's record of each: the
# segmentation's archive (segment job), the calibration, the analysis' archive (validation,
# diagnosis, the report's tables, gyrocal/io/unit_folder.py) and the report (this job).
# Each job's log is a part of its archive; what the job cost is the guard's line on its
# stderr (gyrocal/run/guard.py; no benchmark file). The fleet summary reads the calibration
# and the archives. `gyrocal report` rendered after a part was deleted names it.


rule analyse:
    input:
        seg="results/{batch}/{device}/{session}/segmentation.zip",
        other=other_segmentation,
        terms=TERM_FILES,
    output:
        cal="results/{batch}/{device}/{session}/calibration.json",
        analysis="results/{batch}/{device}/{session}/analysis.zip",
        report="reports/{batch}/{device}/{session}.html",
    group:
        "unit"
    conda:
        ENV
    # benchmarks/requests.py: 275 MiB and 6 s at most (full protocol, report included)
    threads: 1
    resources:
        mem_mb=lambda wildcards, attempt: 500 * attempt,
        runtime=lambda wildcards, attempt: 2 * attempt,
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
        "{params.guard} --attempt {resources.attempt} --job-memory-mb {resources.mem_mb} "
        '{params.limits} --job-log "$(dirname {input.seg:q})/analyse.log" '
        "analyse $(dirname {input.seg:q}) {params.args} {params.other} "
        "--report {output.report:q} --record-failures"
