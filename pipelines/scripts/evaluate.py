from ipm.runtime import exit_now
from ipm.workflow import evaluate_step

evaluate_step(reference=snakemake.input.reference, truth=snakemake.input.truth, run=snakemake.input.run,
              metrics=snakemake.output.metrics, preview=snakemake.output.preview, gallery=snakemake.output.gallery,
              row=snakemake.params.row, seed=int(snakemake.wildcards.seed), n_views=snakemake.params.n_views,
              res=snakemake.params.res, grid=snakemake.params.grid, views=snakemake.input.get("views") or None,
              reference_masks=snakemake.input.reference_masks,
              threads=snakemake.threads, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
