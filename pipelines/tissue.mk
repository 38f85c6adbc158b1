# pipelines/tissue.mk — soft-object probing sessions, one stage binary per rule:
#
#   sessions/<S>/session.toml ──capture──▶ <OUT>/<S>/capture.mcap
#                              ──tissue fit──▶ <OUT>/<S>/material.mcap
#                              ──tissue simulate──▶ <OUT>/<S>/sim.mcap   (a novel probe, see SIMULATE_ARGS)
#                              ──diagnose──▶ <OUT>/<S>/diagnosis.mcap, diagnosis.json, report/report.md
#
# Every target is a file; `make -j` rebuilds only what changed and runs independent sessions in
# parallel:
#
#   make -f pipelines/tissue.mk SESSIONS=sessions OUT=out/tissue -j2
#   make -f pipelines/tissue.mk SESSIONS=sessions OUT=out/tissue digests   # one digest per intermediate
#
# SOFTCAP is the umbrella binary; it finds the `softcap-<stage>` binaries next to itself.
SOFTCAP  ?= target/release/softcap
SESSIONS ?= sessions
OUT      ?= out/tissue
# The novel probe `tissue simulate` synthesizes (SI units: a 6 mm sphere pressing 0.5 N straight down
# at the top centre of the suite's 40 × 40 × 20 mm block). A session overrides it with a one-line
# `simulate.args` file in its folder.
SIMULATE_ARGS ?= --probe-shape sphere --radius 0.006 --tip 0.02 0.02 0.03 --axis 0 0 -1 --force 0.5

# The stage binaries next to SOFTCAP are prerequisites of their rules, so a rebuilt stage reruns
# its step and everything downstream (a SOFTCAP found on PATH adds none: $(wildcard) drops it).
STAGE_BIN = $(wildcard $(dir $(SOFTCAP))softcap-$(1))

# A session is any folder of $(SESSIONS) with a session.toml.
SESSION_NAMES := $(patsubst $(SESSIONS)/%/session.toml,%,$(wildcard $(SESSIONS)/*/session.toml))
REPORTS       := $(foreach s,$(SESSION_NAMES),$(OUT)/$(s)/report/report.md)
SIMULATIONS   := $(foreach s,$(SESSION_NAMES),$(OUT)/$(s)/sim.mcap)

.PHONY: all simulations digests clean-tissue
.DELETE_ON_ERROR:
# Keep every intermediate MCAP (they are the point: inspect them between stages).
.SECONDARY:
.SECONDEXPANSION:

all: $(REPORTS) $(SIMULATIONS)

# Only the novel-probe syntheses (bickel2009 §3.4) of every session.
simulations: $(SIMULATIONS)

# capture reads the whole session folder except truth/ (which capture never reads).
$(OUT)/%/capture.mcap: $$(shell find $(SESSIONS)/$$* -type f -not -path '*/truth/*' 2>/dev/null) $(call STAGE_BIN,capture)
	@mkdir -p $(@D)
	$(SOFTCAP) capture $(SESSIONS)/$* -o $@

$(OUT)/%/material.mcap: $(OUT)/%/capture.mcap $(SESSIONS)/%/template/volume.msh $(call STAGE_BIN,tissue)
	$(SOFTCAP) tissue fit $< --mesh $(SESSIONS)/$*/template/volume.msh -o $@

# Synthesis with the fitted material (bickel2009 §3.4): a probe not in the session.
$(OUT)/%/sim.mcap: $(OUT)/%/material.mcap $$(wildcard $(SESSIONS)/$$*/simulate.args) $(call STAGE_BIN,tissue)
	$(SOFTCAP) tissue simulate $< $$(cat $(SESSIONS)/$*/simulate.args 2>/dev/null || echo '$(SIMULATE_ARGS)') -o $@

# One rule writes the three diagnosis outputs (GNU make ≥ 4.3 grouped target).
$(OUT)/%/diagnosis.mcap $(OUT)/%/diagnosis.json $(OUT)/%/report/report.md &: $(OUT)/%/capture.mcap $(OUT)/%/material.mcap $(call STAGE_BIN,diagnose)
	$(SOFTCAP) diagnose $(OUT)/$*/capture.mcap $(OUT)/$*/material.mcap \
	    -o $(OUT)/$*/diagnosis.mcap --json $(OUT)/$*/diagnosis.json --report $(OUT)/$*/report

# `softcap inspect digest` of every intermediate, one line per file (what `make verify` compares).
digests: $(REPORTS)
	@for s in $(SESSION_NAMES); do for f in capture material sim diagnosis; do \
	    printf '%s/%s.mcap %s\n' "$$s" "$$f" "$$($(SOFTCAP) inspect digest $(OUT)/$$s/$$f.mcap)"; \
	done; done

clean-tissue:
	rm -rf $(OUT)
