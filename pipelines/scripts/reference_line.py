from ipm.runtime import exit_now
from ipm.workflow import reference_line_step

reference_line_step(name=snakemake.wildcards.name, reference=snakemake.input.reference, truth=snakemake.input.truth,
                    mesh=f"{snakemake.output.run}/mesh.ply", threads=snakemake.threads, log=snakemake.log[0])
exit_now()  # the outputs are written: the job ends without tearing its libraries down
