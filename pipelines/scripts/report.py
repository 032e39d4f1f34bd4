from ipm.runtime import exit_now
from ipm.workflow import report_step

# the views' folders as this job sees them (under a storage prefix on a cluster), per case
views = list(snakemake.input.views)
input_dirs = {case: next(v for v in views if v.endswith(d)) for case, d in snakemake.params.input_dirs.items()}
report_step(table=snakemake.input.table, wide=snakemake.input.wide, summary=snakemake.input.summary,
            metrics=list(snakemake.input.metrics), benchmarks=list(snakemake.input.benchmarks),
            out=snakemake.output.html, config=dict(snakemake.params.config), input_dirs=input_dirs,
            textures=next(iter(snakemake.input.textures), None), log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
