# The two commands a newcomer needs (README "Quick start"): `make main` and `make test`.
# Both set up first (bin/setup.sh is idempotent and fast when nothing changed).
SNAKEMAKE := .venv/bin/snakemake
MAIN_TARGET ?= results/frames/PickCube-v1_dual_128.zarr results/frames/PickCube-v1_dual_128.report.json
CORES ?= 2

.PHONY: setup main test dry-run clean

setup:
	bash bin/setup.sh

main: setup
	$(SNAKEMAKE) --cores $(CORES) $(MAIN_TARGET)
	.venv/bin/ocpipe check-store results/frames/PickCube-v1_dual_128.zarr

test: setup
	.venv/bin/python -m pytest

dry-run: setup
	$(SNAKEMAKE) -n --cores $(CORES)

clean:
	rm -rf results .snakemake
