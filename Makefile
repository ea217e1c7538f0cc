# The two commands a newcomer needs (README "Quick start"): `make main` and `make test`.
# Both set up first (bin/setup.sh is idempotent and fast when nothing changed).
SNAKEMAKE := .venv/bin/snakemake
MAIN_TARGET ?= spatial_grounding
CORES ?= 2

.PHONY: setup main test test-fast test-cluster lint dry-run clean

setup:
	bash bin/setup.sh

main: setup
	$(SNAKEMAKE) --cores $(CORES) --rerun-incomplete $(MAIN_TARGET)
	.venv/bin/ocpipe summary results

# everything but the SLURM tests (marked cluster: they install and start a cluster as root; make test-cluster)
test: setup lint
	.venv/bin/python -m pytest -m "not cluster"

# everyday work: everything but the end-to-end Snakemake runs (tests marked slow)
test-fast: setup
	.venv/bin/python -m pytest -m "not slow"

# the tiny study through the local SLURM cluster (docs/cluster.md): needs root; the first start installs SLURM
# and MariaDB (apt), and the cluster keeps running afterwards (bash bin/slurm-local.sh stop)
test-cluster: setup
	bash bin/slurm-local.sh start && .venv/bin/python -m pytest -m cluster

lint:
	.venv/bin/ruff check .
	.venv/bin/snakefmt --check Snakefile workflow/rules
	$(SNAKEMAKE) --lint

dry-run: setup
	$(SNAKEMAKE) -n --cores $(CORES)

clean:
	rm -rf results .snakemake
