# capsmech — build the Fortran kernel, set up the Python environment, test, demo.
# Two commands do everything on a fresh Debian machine: `make demo` and `make test`.
# Databases: `make database GRID=smoke|paper [PROFILE=local|slurm]`, then `make figures GRID=...`;
# `make folds GRID=...` adds the folds (critical Ca_s) to a tube database made case by case.

SHELL := /bin/bash
.DEFAULT_GOAL := build

FC      ?= gfortran
ifeq ($(origin FC),default)
FC      := gfortran
endif
HDF5_INC ?= /usr/include/hdf5/serial
HDF5_LIB ?= /usr/lib/x86_64-linux-gnu/hdf5/serial
# Two build flavours. The default is built for the machine that builds it (-O3 -march=native:
# AVX2/FMA where the CPU has them, about 2 times faster on the level-4 velocity evaluation than
# the portable build, bench/bench_build_flavours.py). `make PORTABLE=1` builds for any x86-64
# (the baseline ISA, SSE2) for packaging. No -ffast-math in either: results stay IEEE; the
# flavours differ in rounding only (FMA contraction), well inside every test's tolerance.
# Each flavour has its own object directory, and a stamp of the full flags (build/FLAVOUR/flags,
# bin/.flavour) rebuilds the objects and relinks bin/ whenever the flags change, so objects of
# different flavours or flags never mix.
ifeq ($(PORTABLE),1)
FLAVOUR := portable
OPT     ?= -O2 -march=x86-64 -mtune=generic
else
FLAVOUR := native
OPT     ?= -O3 -march=native
endif
FFLAGS  ?= $(OPT) -fopenmp -std=f2018 -Wall -Wextra -Wimplicit-interface -fimplicit-none \
           -ffree-line-length-132 -Wno-maybe-uninitialized -Wno-compare-reals
LDLIBS  := -L$(HDF5_LIB) -lhdf5hl_fortran -lhdf5_hl -lhdf5_fortran -lhdf5 -llapack -lblas

BUILD   := build/$(FLAVOUR)
BIN     := bin
FLAGS_STAMP := $(BUILD)/flags
BIN_STAMP   := $(BIN)/.flavour
VENV    := .venv
PY      := $(VENV)/bin/python

# Modules in dependency order (one concept per module, file name = module name). Each module
# may use any module before it: compiling in list order is the dependency rule. Names not
# (yet) present in kernel/src are skipped.
MODULE_ORDER := capsim_kinds lapack_interfaces blas_threads text_format text_parse file_ops checksum command_args option_table vector_algebra hdf5_writer sphere_mesh triangle_quadrature \
           elliptic_integrals ring_stokeslet ring_stresslet membrane_law membrane_forces membrane_bending axisymmetric_membrane \
           axisymmetric_bending \
            stokes_single_layer stokes_double_layer interface_equation tube_wall_mesh duct_poiseuille duct_wall_mesh wall_mesh_quality triangle_cells wall_single_layer self_single_layer surface_diagnostics background_flow shear_implicit \
           run_options case_output state_vector capsule_model tube_history capsule_dynamics \
           axisymmetric_wall axisymmetric_operator axisymmetric_integrators axisymmetric_steady axisymmetric_continuation axisymmetric_tube tube_branch tube_capsule tube_steady_3d tube_branch_3d
MODULES := $(foreach m,$(MODULE_ORDER),$(if $(wildcard kernel/src/$(m).f90),$(m)))
MOD_OBJS := $(addprefix $(BUILD)/,$(addsuffix .o,$(MODULES)))
# Test programs: every kernel/tests/*.f90 is a program that measures and prints.
PROBES := $(basename $(notdir $(wildcard kernel/tests/*.f90)))
# Kept after linking, so that switching flavour back relinks without recompiling the probes.
.SECONDARY: $(addprefix $(BUILD)/,$(addsuffix .o,$(PROBES)))

.PHONY: build setup system-deps venv test demo bench validate clean clean-kernel database folds figures FORCE

build: system-deps $(BIN)/capsim $(addprefix $(BIN)/,$(PROBES))

system-deps:
	@FC='$(FC)' HDF5_INC='$(HDF5_INC)' HDF5_LIB='$(HDF5_LIB)' bash scripts/setup-system.sh

# The stamps are rewritten only when their content changes (FORCE runs the check every time,
# make then compares times as usual): a change of FC, OPT or FFLAGS recompiles, a change of
# flavour relinks bin/ from that flavour's objects.
$(FLAGS_STAMP): FORCE | $(BUILD)
	@echo '$(FC) $(FFLAGS) -I$(HDF5_INC)' | cmp -s - $@ || echo '$(FC) $(FFLAGS) -I$(HDF5_INC)' > $@

$(BIN_STAMP): FORCE | $(BIN)
	@echo '$(FLAVOUR): $(FC) $(FFLAGS) $(LDLIBS)' | cmp -s - $@ || echo '$(FLAVOUR): $(FC) $(FFLAGS) $(LDLIBS)' > $@

$(BUILD)/%.o: kernel/src/%.f90 $(FLAGS_STAMP) | $(BUILD)
	$(FC) $(FFLAGS) -I$(HDF5_INC) -J$(BUILD) -c $< -o $@

$(BUILD)/%.o: kernel/tests/%.f90 $(MOD_OBJS) $(FLAGS_STAMP) | $(BUILD)
	$(FC) $(FFLAGS) -I$(HDF5_INC) -J$(BUILD) -c $< -o $@

$(foreach i,$(shell seq 2 $(words $(MODULES))),$(eval $(BUILD)/$(word $(i),$(MODULES)).o: $(BUILD)/$(word $(shell expr $(i) - 1),$(MODULES)).o))

$(BUILD)/capsim.o: kernel/src/capsim.f90 $(MOD_OBJS) $(FLAGS_STAMP) | $(BUILD)
	$(FC) $(FFLAGS) -I$(HDF5_INC) -J$(BUILD) -c $< -o $@

$(BIN)/%: $(BUILD)/%.o $(MOD_OBJS) $(BIN_STAMP) | $(BIN)
	$(FC) $(FFLAGS) $(filter %.o,$^) -o $@ $(LDLIBS)

$(BUILD) $(BIN):
	mkdir -p $@

$(PY): requirements.txt analysis/pyproject.toml
	python3 -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --upgrade pip
	$(VENV)/bin/pip install --quiet -r requirements.txt
	$(VENV)/bin/pip install --quiet --no-deps -e analysis
	touch $(PY)

venv: $(PY)

# The package's sdist and, built from it, its wheel (the kernel compiled into it by CMake,
# analysis/CMakeLists.txt, portable flags) in dist/; docs/getting-started.md.
.PHONY: wheel
wheel: venv
	mkdir -p dist && rm -f dist/capsmech-*
	cd analysis && ../$(PY) -c "from scikit_build_core.build import build_sdist; build_sdist('../dist')"
	$(PY) -m pip wheel --no-deps --disable-pip-version-check -w dist dist/capsmech-*.tar.gz

setup: build venv

# The tests run on every core (TEST_WORKERS=0 runs them in pytest's own process). loadscope keeps a
# module's tests, and so its module-scoped fixtures (kernel runs, fitted batches), on one worker.
TEST_WORKERS ?= auto
test: setup
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadscope

# The demo's outputs are replaced on every run (--force). It ends with a newcomer's first kernel
# run, the kernel's defaults alone (those of the shipped shear database): a progress bar while it
# steps, then the steady case's summary (the show line only adds its plot).
demo: setup
	@mkdir -p demo
	$(PY) -m capsmech.cli fit-tube data/examples/tube_batch_NH.csv --database tube-paper \
	    --law NH --law GH_nu0.5 --out demo/fit_tube_batch_NH.csv --force
	$(PY) -m capsmech.cli population demo/fit_tube_batch_NH.csv --plot demo/population_NH.png \
	    --out demo/population_NH.csv --force
	$(PY) -m capsmech.cli simulate --flow shear --law NH --ca 0.05 --out demo/shear_NH_Ca0.05.h5 --force
	$(PY) -m capsmech.cli show demo/shear_NH_Ca0.05.h5 --plot demo/shear_NH_Ca0.05.png --force > /dev/null
	@echo "demo: wrote demo/shear_NH_Ca0.05.png (its history and profile)"

# Timings of the default (native) build; bench_build_flavours.py builds both flavours into
# build/bench-*/ and prints the portable/native ratio; bench_elliptic.py the elliptic integrals' ratio
# per call (with --baseline OTHER/bin, tube cases against an older build).
bench: build venv
	$(PY) bench/bench_single_layer.py
	$(PY) bench/bench_tube_axi.py
	$(PY) bench/bench_tube_3d.py
	$(PY) bench/bench_inverse.py
	$(PY) bench/bench_build_flavours.py
	$(PY) bench/bench_elliptic.py

validate: setup
	$(PY) -m pytest -m validate

# Database workflow (workflow/, config/$(GRID).yaml). Snakemake prints "N of M steps (P%) done"
# as cases finish. A run killed at any point is resumed by the same command: the lock a killed
# run leaves is removed first (only when no Snakemake process works in this directory).
GRID    ?= smoke
PROFILE ?= local
SNAKEMAKE := $(VENV)/bin/snakemake -s workflow/Snakefile --configfile config/$(GRID).yaml \
             --profile workflow/profiles/$(PROFILE)

# On SLURM, the jobs a killed run left in the queue are first cancelled (RECOVER=cancel, the
# default: their cases resume from their checkpoints) or waited for (RECOVER=wait), so that no
# case is computed by two jobs at once (docs/jobs/cluster.md).
database: setup
	@$(PY) -m capsmech.cli dev check-grid config/$(GRID).yaml
	$(PY) -m capsmech.cli dev unlock-stale . --profile workflow/profiles/$(PROFILE) $(if $(RECOVER),--on-old-jobs $(RECOVER))
	$(SNAKEMAKE)

# Where each steady branch of a grid's tube database ends (the folds: critical Ca_s per law and
# a/l), by the kernel's continuation, added to the database without refilling its rows
# (scripts/add_folds.py; LAWS="NH SK_C1" for some laws, JOBS=2 branches at once).
folds: setup
	$(PY) scripts/add_folds.py config/$(GRID).yaml $(if $(LAWS),--laws $(LAWS)) --jobs $(or $(JOBS),1)

# Redraw the figures from the grid's databases as they are (no case is run).
figures: venv
	$(PY) -m capsmech.cli figures --grid config/$(GRID).yaml

clean-kernel:
	rm -rf build $(BIN)

clean: clean-kernel
	rm -rf $(VENV) demo

# Documentation site (mkdocs.yml, docs/): the CLI and API pages are generated at build time;
# --strict makes any warning (a broken link, a docstring griffe cannot read) an error.
.PHONY: docs
docs: venv
	$(VENV)/bin/mkdocs build --strict -d site
