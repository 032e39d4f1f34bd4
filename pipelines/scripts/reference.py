from ipm.workflow import reference_step

reference_step(case=snakemake.wildcards.case, reference=snakemake.output.reference, log=snakemake.log[0])
