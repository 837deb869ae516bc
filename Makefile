# bimtiles — two set-up commands on a fresh Debian machine (as root, or with sudo):
#   make run    installs what is missing, builds, converts the bundled sample into out/ and prints a summary
#   make test   installs what the tests need and runs the whole suite
# Every install step is idempotent: it only acts when something is missing or out of date.

SHELL   := /bin/bash
CARGO   ?= cargo
SHARED  ?= $(abspath ../shared)
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
VENV    := .venv
PY      := $(VENV)/bin/python
BIN     := target/release/bimtiles
SAMPLE  := samples/sample_building.glb
APT_PKGS := pkg-config g++ libdraco-dev nodejs npm python3 python3-venv

.PHONY: run test deps deps-system deps-node deps-python build bench clean

run: deps build
	$(BIN) convert $(SAMPLE) --out out/sample --force --max-tile-triangles 4000
	$(BIN) inspect out/sample

build:
	@command -v $(CARGO) >/dev/null || { echo "error: cargo (Rust toolchain) is required: https://rustup.rs"; exit 1; }
	$(CARGO) build --release

deps: deps-system deps-node deps-python

# Debian packages: only those not installed yet.
deps-system:
	@missing=""; for p in $(APT_PKGS); do \
	  case $$p in nodejs) command -v node >/dev/null && continue;; npm) command -v npm >/dev/null && continue;; \
	    python3) command -v python3 >/dev/null && continue;; python3-venv) python3 -m venv --help >/dev/null 2>&1 && continue;; esac; \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; fi

# npm packages for the independent checks (gltf-validator), pinned by tools/package-lock.json.
deps-node: tools/node_modules/.installed
tools/node_modules/.installed: tools/package.json tools/package-lock.json
	cd tools && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# PyPI packages for the cross-checks (usd-core, jsonschema, DracoPy, pytest), in a local venv.
deps-python: $(VENV)/.installed
$(VENV)/.installed: tests/python/requirements.txt
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
	touch $@

test: deps
	rm -rf target/test-out
	mkdir -p target/test-out/ifc-dump
	BIMTILES_REQUIRE_TOOLS=1 BIMTILES_SHARED=$(SHARED) BIMTILES_DRACO_FIXTURE_DIR=$(CURDIR)/target/test-out/draco-fixtures \
	BIMTILES_IFC_DUMP_DIR=$(CURDIR)/target/test-out/ifc-dump \
	  $(CARGO) test --release
	BIMTILES_SHARED=$(SHARED) BIMTILES_DRACO_FIXTURE_DIR=$(CURDIR)/target/test-out/draco-fixtures \
	BIMTILES_IFC_DUMP_DIR=$(CURDIR)/target/test-out/ifc-dump \
	BIMTILES_TILE_DIR=$(CURDIR)/target/test-out \
	BIMTILES_TILESET_DIRS=$$(find target/test-out -name tileset.json -printf '%h:' | sed 's/:$$//') \
	  $(PY) -m pytest -q tests/python

bench: build
	$(CARGO) run --release --example bench_tiler -- $(SHARED)/data

clean:
	rm -rf target out $(VENV) tools/node_modules
