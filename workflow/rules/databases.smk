# Assemble the case files of each flow into <databases_dir>/<flow>.h5 (provenance: the grid
# as run, recorded in grid.json whenever it changes).


rule grid_record:
    output:
        grid=GRID_RECORD,
    log:
        f"{LOGS}/grid_record.log",
    params:
        content=grid_json(config),
    run:
        Path(output.grid).write_text(params.content)
        Path(log[0]).write_text(f"wrote {output.grid}\n")


rule database:
    input:
        grid=GRID_RECORD,
        kernel_version=rules.kernel_version.output.version,
        cases=case_files,
        branches=branch_files,
    output:
        database=f"{DATABASES}/{{flow}}.h5",
    log:
        f"{LOGS}/database_{{flow}}.log",
    conda:
        "../envs/capsmech.yaml"
    params:
        cases_dir=CASES_DIR,
        branches=lambda wildcards, input: (
            f"--branches {BRANCHES_DIR}" if input.branches else ""
        ),
        python=PYTHON,
    shell:
        "{params.python} -m capsmech.cli database assemble --grid {input.grid} --flow {wildcards.flow}"
        " --cases {params.cases_dir} {params.branches} --out {output.database} > {log} 2>&1"


rule databases:
    input:
        database_files(),
