from ipm.runtime import exit_now
from ipm.workflow import table_step

table_step(metrics=list(snakemake.input.metrics), table=snakemake.output.table, wide=snakemake.output.wide,
           summary=snakemake.output.summary, markdown=snakemake.output.markdown,
           cases=list(snakemake.params.cases), log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
