from ipm.workflow import report_check_step

report_check_step(html=snakemake.input.html, out_dir=snakemake.output.screenshots, rows=list(snakemake.params.rows),
                  log=snakemake.log[0])
