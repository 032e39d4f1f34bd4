from ipm.runtime import exit_now
from ipm.workflow import degrade_step

degrade_step(src=snakemake.input.views, dst=snakemake.output.views, slug=snakemake.wildcards.mask,
             seed=int(snakemake.params.seed), log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
