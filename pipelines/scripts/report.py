from ipm.workflow import report_step

report_step(table=snakemake.input.table, wide=snakemake.input.wide, summary=snakemake.input.summary,
            metrics=list(snakemake.input.metrics), out=snakemake.output.html, config=dict(snakemake.params.config),
            input_dirs=dict(snakemake.params.input_dirs), log=snakemake.log[0])
