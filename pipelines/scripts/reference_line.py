from ipm.workflow import reference_line_step

reference_line_step(name=snakemake.wildcards.name, reference=snakemake.input.reference, truth=snakemake.input.truth,
                    mesh=snakemake.output.mesh, threads=snakemake.threads, log=snakemake.log[0])
