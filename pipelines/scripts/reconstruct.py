from ipm.runtime import exit_now
from ipm.workflow import reconstruct_step

reconstruct_step(method=snakemake.params.method, transforms=f"{snakemake.input.views}/transforms.json",
                 mesh=f"{snakemake.output.run}/mesh.ply", generator=snakemake.params.generator,
                 profile=snakemake.params.profile, seed=int(snakemake.wildcards.seed),
                 n_input_views=snakemake.params.n_input_views,
                 prepared=snakemake.input.get("prepared"), settings=snakemake.params.settings,
                 threads=snakemake.threads, log=snakemake.log[0],
                 device=snakemake.params.device)
exit_now()  # the outputs are written: the job ends without tearing its libraries down
