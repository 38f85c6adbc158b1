# pipelines/tissue.mk — soft-object probing sessions, one stage binary per rule:
#
#   sessions/<S>/session.toml ──capture──▶ <OUT>/<S>/capture.mcap
#                              ──tissue fit──▶ <OUT>/<S>/material.mcap
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

# A session is any folder of $(SESSIONS) with a session.toml.
SESSION_NAMES := $(patsubst $(SESSIONS)/%/session.toml,%,$(wildcard $(SESSIONS)/*/session.toml))
REPORTS       := $(foreach s,$(SESSION_NAMES),$(OUT)/$(s)/report/report.md)

.PHONY: all digests clean-tissue
.DELETE_ON_ERROR:
# Keep every intermediate MCAP (they are the point: inspect them between stages).
.SECONDARY:
.SECONDEXPANSION:

all: $(REPORTS)

# capture reads the whole session folder except truth/ (which capture never reads).
$(OUT)/%/capture.mcap: $$(shell find $(SESSIONS)/$$* -type f -not -path '*/truth/*' 2>/dev/null)
	@mkdir -p $(@D)
	$(SOFTCAP) capture $(SESSIONS)/$* -o $@

$(OUT)/%/material.mcap: $(OUT)/%/capture.mcap $(SESSIONS)/%/template/volume.msh
	$(SOFTCAP) tissue fit $< --mesh $(SESSIONS)/$*/template/volume.msh -o $@

# One rule writes the three diagnosis outputs (GNU make ≥ 4.3 grouped target).
$(OUT)/%/diagnosis.mcap $(OUT)/%/diagnosis.json $(OUT)/%/report/report.md &: $(OUT)/%/capture.mcap $(OUT)/%/material.mcap
	$(SOFTCAP) diagnose $(OUT)/$*/capture.mcap $(OUT)/$*/material.mcap \
	    -o $(OUT)/$*/diagnosis.mcap --json $(OUT)/$*/diagnosis.json --report $(OUT)/$*/report

# `softcap inspect digest` of every intermediate, one line per file (what `make verify` compares).
digests: $(REPORTS)
	@for s in $(SESSION_NAMES); do for f in capture material diagnosis; do \
	    printf '%s/%s.mcap %s\n' "$$s" "$$f" "$$($(SOFTCAP) inspect digest $(OUT)/$$s/$$f.mcap)"; \
	done; done

clean-tissue:
	rm -rf $(OUT)
