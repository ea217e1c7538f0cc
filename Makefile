# The two commands a newcomer needs (README "Quick start"): `make main` and `make test`.
# Both set up first (bin/setup.sh is idempotent and fast when nothing changed).
SNAKEMAKE := .venv/bin/snakemake
MAIN_TARGET ?= spatial_grounding
CORES ?= 2

.PHONY: setup main test test-fast lint dry-run clean

setup:
	bash bin/setup.sh

main: setup
	$(SNAKEMAKE) --cores $(CORES) --rerun-incomplete $(MAIN_TARGET)
	.venv/bin/ocpipe summary results

test: setup lint
	.venv/bin/python -m pytest

# everyday work: everything but the end-to-end Snakemake runs (tests marked slow)
test-fast: setup
	.venv/bin/python -m pytest -m "not slow"

lint:
	.venv/bin/ruff check .
	.venv/bin/snakefmt --check Snakefile workflow/rules
	$(SNAKEMAKE) --lint

dry-run: setup
	$(SNAKEMAKE) -n --cores $(CORES)

clean:
	rm -rf results .snakemake
