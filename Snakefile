# gyrocal fleet workflow: per unit and session, segment -> analyse (fit, validate,
# diagnose) -> report, then the fleet summary. Logic lives in the gyrocal package; rules
# only wire files.
from snakemake.utils import min_version

from gyrocal.io.errors import or_exit
from gyrocal.io.schema import check, refuse_duplicate_keys

min_version("9.0")


configfile: "config/config.yaml"


# Checked against gyrocal/io/schemas/config.schema.yaml and completed with its defaults, as
# the command line checks the settings it reads: the same bounds, defaults and messages. A
# key given twice in a config file (a second models: pasted below the first) is refused.
for path in workflow.configfiles:
    or_exit(refuse_duplicate_keys, open(path).read(), source=path)
config.update(
    or_exit(
        check, config, source=" + ".join(map(str, workflow.configfiles)) or "--config"
    )
)


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/segment.smk"
include: "workflow/rules/analyse.smk"
include: "workflow/rules/fleet.smk"
include: "workflow/rules/paper.smk"


rule all:
    input:
        unit_reports(),
        "reports/index.html",
        "results/report_bundle",
        "results/eol.json",
