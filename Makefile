# bimtiles — two set-up commands on a fresh Debian machine (as root, or with sudo):
#   make run    installs what is missing, builds, converts the bundled sample into out/ and prints a summary
#   make test   installs what the tests need and runs the whole suite (the book's checks included)
#   make docs   builds the book (docs/, mdBook) into target/book/ and checks it
# Every install step is idempotent: it only acts when something is missing or out of date.

SHELL   := /bin/bash
CARGO   ?= cargo
SHARED  ?= $(abspath ../shared)
SUDO    := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
VENV    := .venv
PY      := $(VENV)/bin/python
BIN     := target/release/bimtiles
SAMPLE  := samples/sample_building.glb
# What building and running the converter needs (make run), and what only the tests and benches
# need on top (make test).
APT_BUILD_PKGS := pkg-config g++ libdraco-dev libproj-dev proj-data
APT_TEST_PKGS  := nodejs npm python3 python3-venv chromium fonts-dejavu-core assimp-utils
APT_PKGS := $(APT_BUILD_PKGS) $(APT_TEST_PKGS)

.PHONY: run test lint fuzz deps-fuzz test-browser test-clients bench-browser bench-scale serve deps deps-build deps-system deps-node deps-python deps-docs docs screenshot build bench clean

run: deps-build build
	$(BIN) convert $(SAMPLE) --out out/sample --force --max-tile-triangles 4000
	$(BIN) inspect out/sample

build:
	@command -v $(CARGO) >/dev/null || { echo "error: cargo (Rust toolchain) is required: https://rustup.rs"; exit 1; }
	$(CARGO) build --release

deps: deps-system deps-node deps-python deps-docs

# Debian packages: only those not installed yet (deps-build: the converter's alone).
deps-build:
	@$(MAKE) --no-print-directory deps-system APT_PKGS="$(APT_BUILD_PKGS)"

deps-system:
	@missing=""; for p in $(APT_PKGS); do \
	  case $$p in nodejs) command -v node >/dev/null && continue;; npm) command -v npm >/dev/null && continue;; \
	    python3) command -v python3 >/dev/null && continue;; python3-venv) python3 -m venv --help >/dev/null 2>&1 && continue;; \
	    chromium) command -v chromium >/dev/null && continue;; esac; \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then echo "installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $$missing; fi

# npm packages for the independent checks (gltf-validator, ktx-parse) and the browser tests (cesium,
# playwright-core), pinned by tools/package-lock.json.
deps-node: tools/node_modules/.installed
tools/node_modules/.installed: tools/package.json tools/package-lock.json
	cd tools && npm ci --no-audit --no-fund --loglevel=error
	touch $@

# PyPI packages for the cross-checks (usd-core, jsonschema, DracoPy, pytest, pytest-xdist), in a local venv.
deps-python: $(VENV)/.installed
$(VENV)/.installed: tests/python/requirements.txt
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
	touch $@

# mdBook for the book (make docs): pinned, with no default features (no server, watcher or search
# index: `mdbook build` alone), installed from crates.io into cargo's bin folder when that version
# is missing. python3 runs the docs checks.
MDBOOK_VERSION := 0.5.4
MDBOOK := $(or $(CARGO_HOME),$(HOME)/.cargo)/bin/mdbook
deps-docs:
	@$(MAKE) --no-print-directory deps-system APT_PKGS="python3"
	@[ "$$($(MDBOOK) --version 2>/dev/null)" = "mdbook v$(MDBOOK_VERSION)" ] || \
	  $(CARGO) install mdbook --locked --version $(MDBOOK_VERSION) --no-default-features

# Fuzzing (the book, "Safety"): every cargo-fuzz target in fuzz/ runs FUZZ_SECONDS, one after the
# other, on the nightly toolchain (cargo-fuzz comes from crates.io when missing). New inputs go
# to target/fuzz-corpus/<target>/ (the checked-in seeds in fuzz/corpus/ stay as they are), crashes
# to fuzz/artifacts/<target>/: copy each into fuzz/corpus/<target>/ once fixed, and
# tests/fuzz_corpus.rs replays it in `make test`. No sanitizer: our readers are safe Rust, the C++
# decoders the glTF reader calls (Debian's libdraco, meshoptimizer) are not instrumented either way
# (a memory error there shows as a crash), and ASan would halve the executions.
FUZZ_SECONDS ?= 600
FUZZ_TARGETS := gltf ifc manifest citygml image inspect http_head obj fbx
deps-fuzz:
	@rustup toolchain list | grep -q '^nightly' || rustup toolchain install nightly --profile minimal
	@command -v cargo-fuzz >/dev/null || $(CARGO) install cargo-fuzz --locked

fuzz: deps-system deps-fuzz
	cd fuzz && $(CARGO) +nightly fuzz build -s none
	@set -e; for t in $(FUZZ_TARGETS); do mkdir -p target/fuzz-corpus/$$t; \
	  echo "fuzz: $$t for $(FUZZ_SECONDS) s"; \
	  (cd fuzz && $(CARGO) +nightly fuzz run -s none $$t ../target/fuzz-corpus/$$t corpus/$$t -- \
	    -max_total_time=$(FUZZ_SECONDS) -timeout=30 -rss_limit_mb=4096 \
	    -print_final_stats=1); done

# Formatting and lints, as CI runs them before the tests (the build script needs libdraco-dev).
lint: deps-build
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets --features charts -- -D warnings

# The venv's python3 (numpy, for make_campus.py in tests/shard.rs) comes first on PATH.
test: deps
	rm -rf target/test-out
	mkdir -p target/test-out/ifc-dump
	PATH=$(CURDIR)/$(VENV)/bin:$$PATH BIMTILES_REQUIRE_TOOLS=1 BIMTILES_SHARED=$(SHARED) BIMTILES_DRACO_FIXTURE_DIR=$(CURDIR)/target/test-out/draco-fixtures \
	BIMTILES_IFC_DUMP_DIR=$(CURDIR)/target/test-out/ifc-dump \
	  $(CARGO) test --release
	BIMTILES_SHARED=$(SHARED) BIMTILES_DRACO_FIXTURE_DIR=$(CURDIR)/target/test-out/draco-fixtures \
	BIMTILES_IFC_DUMP_DIR=$(CURDIR)/target/test-out/ifc-dump \
	BIMTILES_TILE_DIR=$(CURDIR)/target/test-out \
	BIMTILES_TILESET_DIRS=$$(find target/test-out -name tileset.json -printf '%h:' | sed 's/:$$//') \
	  $(PY) -m pytest -q -n auto --dist loadfile tests/python
	$(MAKE) --no-print-directory test-browser
	$(MAKE) --no-print-directory test-clients
	$(MAKE) --no-print-directory docs

# Real CesiumJS in headless Chromium (software WebGL) loads each tileset the suite wrote: every
# tile loads, none fails, no console error, no request leaves loopback, the model is drawn (one
# KTX2 tileset among them, a textured CityGML building and a textured OBJ district, whose centre
# (or a point near it: a street can lie there) must pick an element and whose faces must show
# their images (neighbouring pixels of one face differ in colour, as they do not on an untextured
# model), and ladder-airport, the wide textured
# airport of tests/hlod.rs); on the
# sample, the adaptive strategy moves the SSE within its bounds. In INLINED_SETS the root's GLB is
# inside tileset.json as a data URI (the default for a small self-contained root): checked here,
# so the browser test keeps loading one.
# The server logs every connection and request (BIMTILES_SERVE_LOG=1); a failing run prints that
# log and the requests still open. (Tile requests that stayed pending for 120 s, seen once on
# 2026-11-25, were tiny_http leaving a new connection unread: fixed in src/serve/, no retry.)
BROWSER_SETS := sample shared-AC20-FZK-Haus shared-duplex shared-ISSUE_021_Mini_Project shared-LoD3_Railway shared-IfcOpenHouse_IFC4 ifc-AC20-FZK-Haus ktx2-LoD3_Railway cityjson-3dbag-5907-subset citygml-citygml4j-lod3-building-textured-lod3_building_v2 mesh-formats-AlphaVille_CenterPart ladder-airport
INLINED_SETS := shared-IfcOpenHouse_IFC4 ifc-AC20-FZK-Haus
# The BIM tools (viewer/bim.js) in one more browser, on two of the tilesets above and a campus
# (tools/viewer_test.mjs): tree, hide and isolate on duplex; search, colour by class, section
# box, plan cut and the URL state on the FZK house; the tree and search budgets on the campus;
# ARIA roles and the element index fetched after the first view on each.
VIEWER_SETS := duplex=target/test-out/shared-duplex/tiles fzk=target/test-out/shared-AC20-FZK-Haus/tiles campus=target/test-out/viewer-campus/tiles
# The campus of the tree and search budgets: 100 buildings of the shared GLBs, about 100k elements,
# converted here without HLOD (only its element index is measured; the tiles need not be coarse).
VIEWER_CAMPUS := $(SHARED)/data/ISSUE_021_Mini_Project.glb=36 $(SHARED)/data/duplex.glb=32 $(SHARED)/data/AC20-FZK-Haus.glb=32
# Edges in the same browser (checkEdges): the sample and an IFC model, converted here with
# --edges all (the cargo tests write none to keep): with the Edges box on, a dark line along known
# hard edges (box edges of picked elements whose surface reaches them); off, none.
EDGE_SETS := edges-sample=$(SAMPLE) edges-duplex=$(SHARED)/data/duplex.ifc
test-browser: deps build
	@set -e; for s in $(EDGE_SETS); do n=$${s%%=*}; $(BIN) convert $${s#*=} --out target/test-out/$$n/tiles --force --quiet --edges all; done
	@$(PY) tools/campus_manifest.py --out target/test-out/viewer-campus $(VIEWER_CAMPUS) && \
	  $(BIN) convert --manifest target/test-out/viewer-campus/campus.json --out target/test-out/viewer-campus/tiles --force --quiet --lod none
	@set -e; for s in $(BROWSER_SETS); do d=target/test-out/$$s/tiles; [ -f $$d/tileset.json ] || { echo "browser test: $$s: the cargo tests wrote no $$d/tileset.json"; exit 1; }; \
	  case " $(INLINED_SETS) " in *" $$s "*) grep -Eq '"uri": *"data:model/gltf-binary;base64,' $$d/tileset.json || { echo "browser test: $$s: the root is not inlined in tileset.json"; exit 1; };; esac; \
	  echo "browser test: $$s"; pick=""; case $$s in sample) pick="--require-pick --check-adaptive";; cityjson-*|shared-IfcOpenHouse_IFC4) pick=--require-pick;; citygml-*|mesh-formats-*) pick="--require-pick --require-texture 0.015";; ladder-airport) pick="--min-drawn-pct 0.1";; esac; \
	  log=target/test-out/$$s.browser.log; \
	  BIMTILES_SERVE_LOG=1 node tools/browser_test.mjs --server-cmd "$(BIN) serve $$d --port 0" \
	    --out target/test-out/$$s.png $$pick > $$log 2>&1 || { cat $$log; exit 1; }; tail -n 1 $$log; done
	@echo "viewer test (BIM tools): $(VIEWER_SETS)"; log=target/test-out/viewer.browser.log; \
	  node tools/viewer_test.mjs --bin $(BIN) $(foreach s,$(VIEWER_SETS) $(foreach e,$(EDGE_SETS),$(firstword $(subst =, ,$(e)))=target/test-out/$(firstword $(subst =, ,$(e)))/tiles),--set $(s)) \
	    --json target/test-out/viewer.json > $$log 2>&1 || { cat $$log; exit 1; }; tail -n 1 $$log

# Client compatibility matrix (tools/clients/): the tilesets of CLIENTS_SETS, which the
# cargo tests wrote (IFC, GLB, textured, CityJSON and KTX2 models with the default options), and
# the variants of CLIENTS_VARIANTS converted here (a Draco one, and each client's profile on a few
# models), loaded in 3DTilesRendererJS (three.js) and deck.gl's Tile3DLayer in one headless
# Chromium (a page per set, everything served from loopback, the pages bundled by esbuild), and in
# loaders.gl in Node. For each client and set: every tile loads and none fails, the frame is drawn
# (pixels), the metadata of a picked (three) or sampled (deck.gl, loaders.gl) feature is read,
# every instanced copy is drawn (counted against the GLBs' EXT_mesh_gpu_instancing) and the colours
# are there (non-grey pixels). What a client cannot do is asserted as its documented limitation
# (tools/clients/expectations.mjs), so a newer client that can fails the check and the table is
# updated. One JSON line per (client, set) in target/test-out/clients.log, all in clients.json.
# Profiles: one variable each, the `--client` profiles (and a Draco variant of the default).
CLIENTS_SETS := shared-duplex shared-AC20-FZK-Haus shared-ISSUE_021_Mini_Project shared-LoD3_Railway shared-IfcOpenHouse_IFC4 ifc-AC20-FZK-Haus cityjson-3dbag-5907-subset ktx2-LoD3_Railway
CLIENTS_PROFILE_DRACO    := --compression draco --no-inline-root
CLIENTS_PROFILE_DECKGL   := --client deckgl
CLIENTS_PROFILE_THREE    := --client three
CLIENTS_PROFILE_PORTABLE := --client portable
# NAME=MODEL:PROFILE, MODEL from $(SHARED)/data, converted like the shared sets (5000 triangles a tile).
CLIENTS_VARIANTS := draco-duplex=duplex.glb:DRACO deckgl-ISSUE_021_Mini_Project=ISSUE_021_Mini_Project.glb:DECKGL \
  deckgl-duplex=duplex.glb:DECKGL three-ISSUE_021_Mini_Project=ISSUE_021_Mini_Project.glb:THREE \
  portable-LoD3_Railway=LoD3_Railway.glb:PORTABLE
# Where the cargo tests' tilesets are (make test-clients CLIENTS_FROM=... to reuse another checkout's).
CLIENTS_FROM ?= target/test-out
test-clients: deps build
	@set -e; args=""; for s in $(CLIENTS_SETS); do d=$(CLIENTS_FROM)/$$s/tiles; \
	  [ -f $$d/tileset.json ] || { echo "client matrix: $$s: the cargo tests wrote no $$d/tileset.json"; exit 1; }; args="$$args $$s=$$d"; done; \
	for v in $(CLIENTS_VARIANTS); do name=$${v%%=*}; rest=$${v#*=}; model=$${rest%%:*}; \
	  case $${rest##*:} in DRACO) opts="$(CLIENTS_PROFILE_DRACO)";; DECKGL) opts="$(CLIENTS_PROFILE_DECKGL)";; \
	    THREE) opts="$(CLIENTS_PROFILE_THREE)";; PORTABLE) opts="$(CLIENTS_PROFILE_PORTABLE)";; *) echo "bad variant $$v"; exit 1;; esac; \
	  d=target/test-out/clients-$$name/tiles; $(BIN) convert $(SHARED)/data/$$model --out $$d --force --quiet --max-tile-triangles 5000 $$opts; \
	  args="$$args $$name=$$d"; done; \
	log=target/test-out/clients.log; echo "client matrix: three, deckgl, loadersgl on $$(echo $$args | sed 's/=[^ ]*//g')"; \
	node tools/clients/run.mjs --json target/test-out/clients.json $$args > $$log 2>&1 || { cat $$log; exit 1; }; tail -n 1 $$log

# The book: the CLI reference is written again from the clap definitions (examples/cli_reference.rs)
# and must equal the committed page (else it is replaced and make fails: commit the new page), then
# mdBook builds target/book/ and tools/check_docs.py checks every link and anchor of the book and
# the README, the README's rules, and that the reference pages name every report.json key (of a
# report the current binary writes), schema property and dependency.
docs: deps-docs build
	@mkdir -p target/docs
	$(CARGO) run --release --quiet --example cli_reference -- target/docs/cli.md
	@cmp -s target/docs/cli.md docs/src/reference/cli.md || { cp target/docs/cli.md docs/src/reference/cli.md; \
	  echo "docs: docs/src/reference/cli.md differed from the clap definitions: regenerated, commit it"; exit 1; }
	$(MDBOOK) build docs
	$(BIN) convert --out target/docs/sample --force --quiet
	python3 tools/check_docs.py --report target/docs/sample/report.json

# The README's and the book's screenshots, taken by the browser tests: a shared IFC model converted
# with the default options, loaded in the viewer at full resolution (a click must pick an element),
# then its BIM tools (tree and isolate, colour by class, section box); and edges off and on
# (edges-ifc-*.png, edges-campus-*.png) on the same model and on a small campus of shared
# buildings (make_campus.py, numpy from the venv), both converted with --edges all.
SCREENSHOT_MODEL ?= $(SHARED)/data/AC20-FZK-Haus.ifc
SCREENSHOT_CAMPUS := $(addprefix $(SHARED)/data/,AC20-FZK-Haus.glb duplex.glb IfcOpenHouse_IFC4.glb)
screenshot: deps build
	mkdir -p target/screenshot
	$(BIN) convert $(SCREENSHOT_MODEL) --out target/screenshot/tiles --force --quiet
	$(BIN) convert $(SCREENSHOT_MODEL) --out target/screenshot/ifc-edges --force --quiet --edges all
	$(PY) $(SHARED)/data/make_campus.py target/screenshot/campus.glb --copies 9 --inputs $(SCREENSHOT_CAMPUS)
	$(BIN) convert target/screenshot/campus.glb --out target/screenshot/campus-edges --force --quiet --edges all
	node tools/browser_test.mjs --server-cmd "$(BIN) serve target/screenshot/tiles --port 0" \
	  --query "msaa=4&scale=1" --require-pick --out docs/src/images/viewer.png
	node tools/viewer_test.mjs --bin $(BIN) --set fzk=target/screenshot/tiles --set ifc=target/screenshot/ifc-edges \
	  --set campus=target/screenshot/campus-edges --shots docs/src/images

# Raw model (one-tile tileset) vs our tileset in real CesiumJS, cold and warm (tile cache) loads:
# load time, bytes, memory, frame cost -> target/bench/browser.json, then the charts
# (fig13..fig16 PNGs) and the table (browser.md) drawn from it by examples/bench_charts.rs.
# BENCH_RUNS=N changes the runs per model; BENCH_ARGS adds options (e.g. --runs-for NAME=1);
# BENCH_THROTTLE=20:40 emulates a 20 Mbit/s network with 40 ms latency (no service worker then).
# Each load is followed by the fly-in (bytes fetched at 20, 6, 2.5, 1.2, 0.6 bounding radii).
# Models that are no GLB, textured city data beside the GLBs: a CityGML tile of buildings and an
# OBJ district (their raw variant is our own single-tile GLB of each, see the script's header).
BENCH_BROWSER_CITY = $(wildcard $(SHARED)/data/citygml/plateau-yokosuka-bldg-textured/52397519_bldg_6697_op.gml \
  $(SHARED)/data/obj/alphaville-centerpart-textured/AlphaVille_CenterPart.obj)
BENCH_RUNS ?= 3
BENCH_THROTTLE ?=
bench-browser: deps build
	mkdir -p target/bench
	@# A model that fails is listed in the table; the charts are drawn from the others, then make fails.
	node tools/bench_browser.mjs --runs $(BENCH_RUNS) $(if $(BENCH_THROTTLE),--throttle $(BENCH_THROTTLE)) $(BENCH_ARGS) --json target/bench/browser.json \
	  $(SAMPLE) $(wildcard $(SHARED)/data/*.glb) $(BENCH_BROWSER_CITY) > target/bench/browser.stdout; rc=$$?; \
	  $(CARGO) run --release --quiet --features charts --example bench_charts -- target/bench/browser.json target/bench && exit $$rc

# Convert the sample and open it in the viewer at http://127.0.0.1:8080/
serve: deps build
	$(BIN) convert $(SAMPLE) --out out/sample --force --quiet --max-tile-triangles 4000
	$(BIN) serve out/sample

# make_campus.py needs numpy: the venv's python3 comes first on PATH.
# Each table is kept in target/bench/ and written into the book's benchmarks page with the date,
# commit and machine (tools/bench_page.py); the hand-kept figures below it stay as they are.
bench: deps build
	mkdir -p target/bench
	set -o pipefail; PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(CARGO) run --release --quiet --example bench_tiler -- $(SHARED)/data | tee target/bench/tiler.txt
	set -o pipefail; $(CARGO) run --release --quiet --example bench_textures -- $(SHARED)/data | tee target/bench/textures.txt
	set -o pipefail; $(CARGO) run --release --quiet --example bench_update -- $(SHARED)/data | tee target/bench/update.txt
	python3 tools/bench_page.py docs/src/benchmarks.md \
	  --run "cargo run --release --example bench_tiler -- ../shared/data" target/bench/tiler.txt \
	  --run "cargo run --release --example bench_textures -- ../shared/data" target/bench/textures.txt \
	  --run "cargo run --release --example bench_update -- ../shared/data" target/bench/update.txt

# The scale measurements (not in `make test`; about 25 minutes on 2 cores, most of it the 100M campuses):
# campuses of about 1M, 8.2M, 32M and 100M triangles from make_campus.py --bake, exact and jittered
# (cached in target/bench/scale/, about 7 GB), each converted with the default options (seconds, peak
# memory, output bytes, tiles), the growth exponents, and a sharded build: its jobs one after another
# against tools/ray_driver.py on a local 2-CPU Ray cluster (loopback only, inside `unshare -n`)
# -> target/bench/scale/{scale.json,scale.md,scale.png}. GNU time (Debian `time`) gives each
# process's own max RSS. BENCH_SCALE_ARGS adds options, e.g. --sizes 1M,8M --skip-ray (see
# examples/bench_scale.rs).
BENCH_SCALE_ARGS ?=
bench-scale: deps build
	@[ -x /usr/bin/time ] || { $(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq time; } \
	  || echo "note: no GNU time; peak memory from report.json only"
	BIMTILES_SHARED=$(SHARED) $(CARGO) run --release --features charts --example bench_scale -- --python $(CURDIR)/$(PY) $(BENCH_SCALE_ARGS)

clean:
	rm -rf target out $(VENV) tools/node_modules
