# Build the kernel when it is missing or its sources are newer. Cases take the executable
# as ancient() input: rebuilding it does not make them stale, a new code_version does.


rule kernel:
    input:
        sources=KERNEL_SOURCES,
        makefile=str(REPO / "Makefile"),
    output:
        kernel=KERNEL,
    log:
        f"{LOGS}/kernel.log",
    params:
        repo=lambda wildcards, input: Path(input.makefile).parent,
    threads: 2
    conda:
        "../envs/capsmech.yaml"
    shell:
        "make -C {params.repo} bin/capsim > {log} 2>&1"
