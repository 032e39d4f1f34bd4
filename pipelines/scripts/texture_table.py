from ipm.runtime import exit_now
from ipm.workflow import texture_table_step

texture_table_step(scores=list(snakemake.input.scores), table=snakemake.output.table,
                   markdown=snakemake.output.markdown, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
