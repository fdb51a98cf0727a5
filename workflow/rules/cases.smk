# One case file per (flow, law, a/l, Ca_s). The kernel writes OUT.tmp and renames it when
# complete and resumes from OUT.ckpt, so a killed job leaves no output and is recomputed,
# from its checkpoint, by the next run. A case that ends without a steady state is a
# complete output (status in the file); see capsmech.workflow.runner for non-zero exit codes.
# The params are the case's signature: kernel arguments (law, parameters, the flow's mesh
# and time settings) and code version; a change to either makes exactly that case stale.


rule case:
    input:
        kernel=kernel_executable,
    output:
        case=f"{CASES_DIR}/{{flow}}/{{law}}/{{case}}.h5",
    log:
        f"{LOGS}/cases/{{flow}}/{{law}}/{{case}}.log",
    conda:
        "../envs/capsmech.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=60,
    params:
        kernel_args=lambda wildcards: " ".join(grid_case(wildcards).kernel_args()),
        code_version=CODE_VERSION,
        python=PYTHON,
    shell:
        "{params.python} -m capsmech.cli dev run-case --capsim {input.kernel} --out {output.case}"
        " --code-version {params.code_version} --threads {threads} -- {params.kernel_args}"
        " > {log} 2>&1"
