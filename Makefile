# sonarmap: `make demo` and `make test` are the two commands a new user needs.
# Each target installs what it needs and no more, so a fresh clone needs nothing done by
# hand: `demo` the runtime alone, `test` adds the test tools and the servers its tests start.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
RUNTIME := $(VENV)/.sonarmap-runtime
TESTING := $(VENV)/.sonarmap-test
DOCS := $(VENV)/.sonarmap-docs
# open3d's libraries
RUNTIME_APT := libegl1 libgl1 libx11-6 libusb-1.0-0
# OpenSSH's server and client for the sftp:// sharing tests
TEST_APT := openssh-server openssh-client
TORCH_VERSION := 2.13.0
PYTEST_ARGS ?=
# `make test` runs its files on this many processes (pytest-xdist; one file stays on one
# process, so a module's fixtures are built once): 2 halves its time on the 2-core CI box.
TEST_WORKERS ?= 2

.PHONY: setup setup-test system-deps test test-realtime test-wheel test-without-shared qa demo docs bench lint study clean-store

setup: $(RUNTIME)
setup-test: $(TESTING)

$(RUNTIME): pyproject.toml setup.py Makefile
	@$(MAKE) --no-print-directory system-deps APT="$(RUNTIME_APT)"
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	@# torch first: a bare `torch` requirement would pull a multi-GB CUDA build.
	$(BIN)/python -m pip install -q torch==$(TORCH_VERSION)
	$(BIN)/python -m pip install -q -e .
	@touch $@

$(TESTING): $(RUNTIME)
	@$(MAKE) --no-print-directory system-deps APT="$(TEST_APT)"
	$(BIN)/python -m pip install -q -e '.[dev,ray,remotes]'
	@touch $@

$(DOCS): $(RUNTIME)
	$(BIN)/python -m pip install -q -e '.[docs]'
	@touch $@

system-deps:
	@missing=""; for p in $(APT); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	  else echo "error: sonarmap needs Debian packages:$$missing; run: sudo apt-get install -y$$missing" >&2; exit 2; fi; \
	fi

test: $(TESTING)
	$(BIN)/python -m pytest -m "not wheel and not realtime" -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

# The tests whose length the wall clock sets, not computing (follow mapping a recording
# written at its own pace; a push whose link goes silent until its timeout): about 70 s.
test-realtime: $(TESTING)
	$(BIN)/python -m pytest -m realtime $(PYTEST_ARGS)

# The wheel built from the sdist, installed into a fresh virtual environment, runs the demo
# from a directory outside the checkout.
test-wheel: $(TESTING)
	$(BIN)/python -m pytest -m wheel tests/test_wheel.py

# The tests that read ../shared/data, with it hidden as in a user's clone: each must skip.
test-without-shared: $(TESTING)
	SONARMAP_SHARED_DATA=/nonexistent $(BIN)/python -m pytest -m shared_data

# The contract suite (tests/contract, left out of `make test`): each case runs `sonarmap` on a
# hostile input as a user would and checks exit code, one-line error, memory and time; it ends
# with the table of cases tried and held per area (also: python -m tests.contract.run).
qa: $(TESTING)
	$(BIN)/python -m pytest tests/contract $(PYTEST_ARGS)

# `make demo DEMO_ARGS="--set keyframes.submap_stride=1"`: the demo with dense submaps
DEMO_ARGS ?=
demo: $(RUNTIME)
	$(BIN)/sonarmap demo $(DEMO_ARGS)

# The documentation site (mkdocs.yml, docs/) into site/; the CLI, config and column
# references are generated from the code at build time (docs/hooks.py).
docs: $(DOCS)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

bench: $(TESTING)
	$(BIN)/python benchmarks/run_all.py

study: $(RUNTIME)
	$(BIN)/sonarmap study

lint: $(TESTING)
	$(BIN)/ruff check .

clean-store:
	rm -rf data/store
