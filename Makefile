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

.PHONY: setup system-deps test qa demo bench lint study clean-store

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

# The contract suite (tests/contract, left out of `make test`): each case runs `sonarmap` on a
# hostile input as a user would and checks exit code, one-line error, memory and time; it ends
# with the table of cases tried and held per area (also: python -m tests.contract.run).
qa: setup
	$(BIN)/python -m pytest tests/contract $(PYTEST_ARGS)

# `make demo DEMO_ARGS="--set keyframes.submap_stride=1"`: the demo with dense submaps
DEMO_ARGS ?=
demo: setup
	$(BIN)/sonarmap demo $(DEMO_ARGS)

bench: setup
	$(BIN)/python benchmarks/run_all.py

study: setup
	$(BIN)/sonarmap study

lint: setup
	$(BIN)/ruff check .
	$(BIN)/mypy pipeline schemas

clean-store:
	rm -rf data/store
