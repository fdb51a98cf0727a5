# The paper's figures from one database: tube -> figures 2-5, shear -> figure 6 (PNG + PDF).


rule figures:
    input:
        database=f"{DATABASES}/{{flow}}.h5",
        grid=GRID_RECORD,
    output:
        figures=directory(f"{FIGURES}/{{flow}}"),
    log:
        f"{LOGS}/figures_{{flow}}.log",
    conda:
        "../envs/capsmech.yaml"
    params:
        python=PYTHON,
    shell:
        "{params.python} -m capsmech.cli figures --database {input.database} --grid {input.grid}"
        " --out {output.figures} > {log} 2>&1"
