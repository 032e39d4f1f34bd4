from ipm.workflow import report_step

report_step(table=snakemake.input.table, wide=snakemake.input.wide, metrics=list(snakemake.input.metrics),
            out=snakemake.output.html, config=dict(snakemake.params.config), log=snakemake.log[0])
