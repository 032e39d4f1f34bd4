from ipm.workflow import table_step

table_step(metrics=list(snakemake.input.metrics), table=snakemake.output.table, wide=snakemake.output.wide,
           log=snakemake.log[0])
