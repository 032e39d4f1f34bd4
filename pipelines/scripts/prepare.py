from ipm.runtime import exit_now
from ipm.workflow import prepare_step

prepare_step(method=snakemake.wildcards.method, generator=snakemake.wildcards.generator, out=snakemake.output[0],
             profile=snakemake.params.profile, seed=int(snakemake.wildcards.seed), threads=snakemake.threads,
             log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
