# The seed papers' tables regenerated on simulated data, beside the published values.
# Not part of `rule all`: run it by name (`snakemake paper`); it reads no fleet data.


rule paper:
    output:
        md="paper/tables.md",
        csv="paper/tables.csv",
        html="paper/index.html",
    log:
        "logs/paper.log",
    benchmark:
        "results/benchmark/paper.tsv"
    conda:
        ENV
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        gyrocal=GYROCAL,
        seed=0,
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} paper --out $(dirname {output.md:q}) --seed {params.seed} "
        "> {log:q} 2>&1"
