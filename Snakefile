# gyrocal fleet workflow: per unit and session, segment -> analyse (fit, validate,
# diagnose) -> report, then the fleet summary. Logic lives in the gyrocal package; rules
# only wire files.
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "config/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/segment.smk"
include: "workflow/rules/analyse.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/fleet.smk"
include: "workflow/rules/paper.smk"


rule all:
    input:
        unit_reports(),
        "reports/index.html",
        "results/report_bundle",
        "results/eol.json",
