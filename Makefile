# softcap: the two commands of the README.
#   make demo     synthesize the embedded default session (a virtual-rig probing session with one
#                 concealed physical effect), run the tissue pipeline over it (capture → tissue fit →
#                 tissue simulate → diagnose) and print the diagnosis verdict and where every file is
#   make test     run the tests (the binaries of cargo test --workspace --tests, two at a time; then --doc)
#   make smoke    the workflow-engine smoke test (Snakemake over one synthesized session)
# and
#   make verify   rerun the demo pipeline from scratch and compare `softcap inspect digest` of every
#                 intermediate with the first run (determinism)
#   make verify-threads  the same digests with RAYON_NUM_THREADS=1 and 2 (scripts/verify-threads)
CARGO      ?= cargo
TARGET_DIR ?= $(or $(CARGO_TARGET_DIR),target)
# The demo binaries are built with Cargo's `demo` profile (Cargo.toml: the test profile's
# optimization without debug info, build-time-only crates unoptimized), so a fresh clone builds
# them in a few minutes. PROFILE=release for fully optimized binaries, PROFILE=test to reuse the
# artifacts of a `cargo test` build.
PROFILE    ?= demo
BIN        := $(TARGET_DIR)/$(if $(filter test dev,$(PROFILE)),debug,$(PROFILE))
SOFTCAP    := $(BIN)/softcap
SCENARIO   ?= fixtures/scenarios/demo.toml
# The novel probe `tissue simulate` synthesizes for the demo session (pipelines/tissue.mk): a
# 6 mm sphere pressing 0.03 N (half the session's largest probe force; the block is very soft).
DEMO_SIMULATE_ARGS ?= --probe-shape sphere --radius 0.006 --tip 0.02 0.02 0.03 --axis 0 0 -1 --force 0.03
OUT        ?= out/demo
# Only the packages the demo runs.
DEMO_PACKAGES := -p softcap_cli -p softcap_synth -p softcap_capture -p softcap_tissue -p softcap_diagnose

.PHONY: demo test smoke verify verify-threads verify-digests build demo-pipeline clean
build:
	$(CARGO) build --target-dir $(TARGET_DIR) --profile $(PROFILE) $(DEMO_PACKAGES) --bins

# Every test of `cargo test --workspace` (unit, integration, doc tests) without building the 26
# examples, which plain `cargo test` links only to see that they build (≈ 120 CPU-s in the test
# profile; `cargo clippy --all-targets` in .ci/run still compiles them).
# scripts/test-binaries builds exactly what `cargo test --workspace --tests` builds and runs the
# same binaries two at a time (cargo runs them one after another, leaving a core idle most of the
# time), then the doc tests.
test:
	CARGO=$(CARGO) scripts/test-binaries
	$(CARGO) test --workspace --doc

# The workflow-engine smoke test: Snakemake (installed into .venv-workflow on first use) runs
# workflow/Snakefile over one small synthesized session.
smoke:
	scripts/workflow-smoke

# The session is regenerated only when the scenario (or the synth binary) changes.
$(OUT)/sessions/demo/session.toml: $(SCENARIO) $(wildcard $(dir $(SOFTCAP))softcap-synth) | build
	@rm -rf $(OUT)/sessions/demo
	@mkdir -p $(OUT)/sessions
	$(SOFTCAP) synth --scenario $(SCENARIO) --out $(OUT)/sessions/demo

demo-pipeline: build $(OUT)/sessions/demo/session.toml
	$(MAKE) --no-print-directory -f pipelines/tissue.mk SOFTCAP=$(SOFTCAP) \
	    SESSIONS=$(OUT)/sessions OUT=$(OUT)/runs SIMULATE_ARGS='$(DEMO_SIMULATE_ARGS)' all

demo: demo-pipeline
	@scripts/demo-summary $(SOFTCAP) $(OUT)

# Rerun the whole pipeline from scratch in the same folders (same arguments) and compare the
# `softcap inspect digest` of every intermediate, and a hash of every synthesized session file.
verify: demo-pipeline
	@$(MAKE) --no-print-directory -s -f pipelines/tissue.mk SOFTCAP=$(SOFTCAP) \
	    SESSIONS=$(OUT)/sessions OUT=$(OUT)/runs SIMULATE_ARGS='$(DEMO_SIMULATE_ARGS)' digests > $(OUT)/digests-first.txt
	@cd $(OUT)/sessions && find . -type f | LC_ALL=C sort | xargs sha256sum >> ../digests-first.txt
	rm -rf $(OUT)/sessions $(OUT)/runs
	$(MAKE) --no-print-directory demo-pipeline
	@$(MAKE) --no-print-directory -s -f pipelines/tissue.mk SOFTCAP=$(SOFTCAP) \
	    SESSIONS=$(OUT)/sessions OUT=$(OUT)/runs SIMULATE_ARGS='$(DEMO_SIMULATE_ARGS)' digests > $(OUT)/digests-rerun.txt
	@cd $(OUT)/sessions && find . -type f | LC_ALL=C sort | xargs sha256sum >> ../digests-rerun.txt
	@cat $(OUT)/digests-first.txt
	@if diff -u $(OUT)/digests-first.txt $(OUT)/digests-rerun.txt; then \
	    echo "verify: the rerun reproduced every session file and every intermediate's digest"; \
	else \
	    echo "verify: FAILED, the rerun differs (see above)" >&2; exit 1; \
	fi

# The digests `verify` compares, of the pipeline already in $(OUT) (scripts/verify-threads).
verify-digests:
	@$(MAKE) --no-print-directory -s -f pipelines/tissue.mk SOFTCAP=$(SOFTCAP) \
	    SESSIONS=$(OUT)/sessions OUT=$(OUT)/runs SIMULATE_ARGS='$(DEMO_SIMULATE_ARGS)' digests
	@cd $(OUT)/sessions && find . -type f | LC_ALL=C sort | xargs sha256sum

# Determinism under parallelism: the demo pipeline with 1 and with 2 rayon threads.
verify-threads: build
	SOFTCAP=$(SOFTCAP) scripts/verify-threads

clean:
	rm -rf $(OUT)
