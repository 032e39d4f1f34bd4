from ipm.runtime import exit_now
from ipm.workflow import synth_step

synth_step(case=snakemake.wildcards.case, transforms=f"{snakemake.output.views}/transforms.json",
           views=snakemake.params.views, res=snakemake.params.res, spp=snakemake.params.spp,
           layout=snakemake.wildcards.layout, threads=snakemake.threads, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
