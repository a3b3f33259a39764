# Segment a unit session's log into one archive (gyrocal/io/unit_folder.py): the
# observations the analyse job reads, the session's record, segments and timeline, and the
# job's log. The log is written beside it while the job runs (gyrocal/run/guard.py --job-log)
# and joins the archive when the job ends well; a job that ends badly leaves it there and
# the guard prints its end. No `log:` directive, which the linter asks for: Snakemake
# makes an empty file of a declared log that is not there when the job ends.


rule segment:
    input:
        log=log_input,
    output:
        seg="results/{batch}/{device}/{session}/segmentation.zip",
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
        "{params.guard} --attempt {resources.attempt} --job-memory-mb {resources.mem_mb} "
        '{params.limits} --job-log "$(dirname {output.seg:q})/segment.log" '
        "segment {params.args} --out $(dirname {output.seg:q}) --record-failures"
