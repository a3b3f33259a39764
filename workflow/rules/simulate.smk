# The built-in demo: logs the demo manifest names under demo.folder are simulated when
# missing. A device is the same simulated unit in every session.


rule simulate:
    output:
        f"{DEMO_LOGS}/{{batch}}/{{device}}/{{session}}.parquet",
    log:
        "logs/simulate/{batch}/{device}/{session}.log",
    benchmark:
        "results/benchmark/simulate/{batch}/{device}/{session}.tsv"
    group:
        "unit"
    conda:
        ENV
    threads: 1
    resources:
        mem_mb=lambda wildcards, attempt: 1500 * attempt,
        runtime=lambda wildcards, attempt: 5 * attempt,
    params:
        gyrocal=GYROCAL,
        preset=config["demo"]["preset"],
        unit=demo_unit_options,
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} simulate --log {output:q} --device {wildcards.device:q} "
        "--batch {wildcards.batch:q} --session {wildcards.session:q} "
        "--preset {params.preset} {params.unit} > {log:q} 2>&1"


# A real recording of the demo, converted to a contract log by `gyrocal import`.
rule import_real:
    input:
        source="data/real/{name}/session.csv",
        map="data/real/{name}/import.yaml",
        sections="data/real/{name}/sections.json",
    output:
        f"{REAL_LOGS}/{{name}}.parquet",
    log:
        "logs/import/{name}.log",
    conda:
        ENV
    threads: 1
    params:
        gyrocal=GYROCAL,
        version=GYROCAL_VERSION,
    shell:
        "{params.gyrocal} import {input.source:q} --map {input.map:q} -o {output:q} > {log:q} 2>&1"
