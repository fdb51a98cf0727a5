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


# A branch grid (tube.settings.branch) computes the tube cases of one (law, a/l) in one kernel
# run, by continuation along the steady branch (capsim --branch-ca), and writes a branch file
# with the critical Ca_s where the steady branch ends. The case files are the case rule's; the
# branch rule is preferred for them. A killed branch resumes from its checkpoint; a branch the
# kernel gives up runs its remaining cases one by one (capsmech.workflow.runner.run_branch).
if BRANCHES:

    ruleorder: tube_branch > case

    rule tube_branch:
        input:
            kernel=kernel_executable,
        output:
            cases=[f"{CASES_DIR}/tube/{{law}}/{{size}}_Ca{ca}.h5" for ca in BRANCH_CA],
            branch=f"{BRANCHES_DIR}/tube/{{law}}/{{size}}.h5",
        log:
            f"{LOGS}/branches/tube/{{law}}/{{size}}.log",
        conda:
            "../envs/capsmech.yaml"
        threads: 1
        resources:
            mem_mb=1000,
            runtime=240,
        params:
            kernel_args=lambda wildcards: " ".join(
                grid_branch(wildcards).kernel_args(
                    CASES_DIR,
                    f"{BRANCHES_DIR}/tube/{wildcards.law}/{wildcards.size}.h5",
                )
            ),
            code_version=CODE_VERSION,
            python=PYTHON,
        shell:
            "{params.python} -m capsmech.cli dev run-branch --capsim {input.kernel}"
            " --code-version {params.code_version} --threads {threads} -- {params.kernel_args}"
            " > {log} 2>&1"
