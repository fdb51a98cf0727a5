# The kernel executable is built by `make build` (`make database` runs it before the
# workflow, so an edited kernel is always rebuilt first); this rule checks the build.
#
# Why no rule builds it here: cases take the executable as ancient() input, so that a
# rebuild of the same code_version does not make them stale (a new code_version does,
# through their params). Snakemake 9 skips the params check of jobs downstream of a pending
# job, so a build job upstream of the cases (triggered by a touched Makefile or by its own
# metadata) would hide exactly the stale cases this workflow must find.
#
# kernel_version runs the built kernel once and fails unless it writes the code_version the
# sources declare (each case checks the same); the databases depend on it, the cases do not.


rule kernel_version:
    input:
        kernel=KERNEL,
    output:
        version=f"{RESULTS}/kernel/code_version.txt",
    log:
        f"{LOGS}/kernel_version.log",
    conda:
        "../envs/capsmech.yaml"
    params:
        expected=CODE_VERSION,
        python=PYTHON,
    shell:
        "{params.python} -m capsmech.cli dev kernel-version --capsim {input.kernel} --expect {params.expected}"
        " --out {output.version} > {log} 2>&1"
