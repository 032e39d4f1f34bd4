from ipm.runtime import exit_now
from ipm.workflow import reference_step

reference_step(case=snakemake.wildcards.case, reference=snakemake.output.reference,
               gallery=snakemake.output.gallery, masks=snakemake.output.masks, n_views=snakemake.params.n_views,
               res=snakemake.params.res, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
