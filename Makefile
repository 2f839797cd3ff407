# sonarmap: `make demo` and `make test` are the two commands a new user needs.
# Every target depends on `setup`, so a fresh clone needs nothing done by hand.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.sonarmap-setup
# open3d's libraries; OpenSSH's server and client for the sftp:// sharing tests
APT_PACKAGES := libegl1 libgl1 libx11-6 libusb-1.0-0 openssh-server openssh-client
TORCH_VERSION := 2.13.0
PYTEST_ARGS ?=

.PHONY: setup system-deps test demo bench lint study docs clean-store

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	@$(MAKE) --no-print-directory system-deps
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	@# torch first: a bare `torch` requirement would pull a multi-GB CUDA build.
	$(BIN)/python -m pip install -q torch==$(TORCH_VERSION)
	$(BIN)/python -m pip install -q -e '.[dev,ray,remotes]'
	@touch $(STAMP)

system-deps:
	@missing=""; for p in $(APT_PACKAGES); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  else echo "error: sonarmap needs Debian packages:$$missing; run: sudo apt-get install -y$$missing" >&2; exit 2; fi; \
	fi

test: setup
	$(BIN)/python -m pytest $(PYTEST_ARGS)

# `make demo DEMO_ARGS="--set keyframes.submap_stride=1"`: the demo with dense submaps
DEMO_ARGS ?=
demo: setup
	$(BIN)/sonarmap demo $(DEMO_ARGS)

bench: setup
	$(BIN)/python benchmarks/run_all.py

study: setup
	$(BIN)/sonarmap study

# The documentation site (mkdocs.yml, docs/) into site/; the CLI, config and column
# references are generated from the code at build time (docs/hooks.py).
DOCS_STAMP := $(VENV)/.sonarmap-docs
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install -q -e '.[docs]'
	@touch $(DOCS_STAMP)

docs: setup $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy pipeline schemas

clean-store:
	rm -rf data/store
