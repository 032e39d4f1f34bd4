from ipm.workflow import degrade_step

degrade_step(src=snakemake.input.views, dst=snakemake.output.views, slug=snakemake.wildcards.mask,
             seed=int(snakemake.params.seed), log=snakemake.log[0])
