from ipm.workflow import reference_step

reference_step(case=snakemake.wildcards.case, reference=snakemake.output.reference,
               gallery=snakemake.output.gallery, log=snakemake.log[0])
