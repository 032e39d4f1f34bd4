from ipm.workflow import evaluate_step

evaluate_step(reference=snakemake.input.reference, truth=snakemake.input.truth, mesh=snakemake.input.mesh,
              timing=snakemake.input.timing, metrics=snakemake.output.metrics, preview=snakemake.output.preview,
              row=snakemake.params.row, seed=int(snakemake.wildcards.seed), n_views=snakemake.params.n_views,
              res=snakemake.params.res, grid=snakemake.params.grid, threads=snakemake.threads, log=snakemake.log[0])
