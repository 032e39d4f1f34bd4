from ipm.runtime import exit_now
from ipm.workflow import parts_preview_step

parts_preview_step(reference=snakemake.input.reference, transforms=f"{snakemake.input.views}/transforms.json",
                   mesh=f"{snakemake.input.run}/mesh.ply", png=snakemake.output.png, threads=snakemake.threads,
                   log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
