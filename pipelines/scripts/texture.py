from ipm.runtime import exit_now
from ipm.workflow import texture_step

texture_step(run=snakemake.input.run, views=snakemake.input.views, out=snakemake.output.scores,
             n_input=int(snakemake.params.n_input),
             appearance=snakemake.params.appearance, row=snakemake.params.row, seed=int(snakemake.wildcards.seed),
             threads=snakemake.threads, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
