from ipm.workflow import parts_preview_step

parts_preview_step(reference=snakemake.input.reference, transforms=snakemake.input.transforms,
                   mesh=snakemake.input.mesh, png=snakemake.output.png, threads=snakemake.threads,
                   log=snakemake.log[0])
