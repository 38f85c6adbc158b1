# pipelines/dynamic.mk — dynamic sessions (depth cameras watching a freely moving object, wang2015;
# docs/dynamic.md), one stage binary per rule:
#
#   <SESSIONS>/<S>/ (session.toml kind = "dynamic", depth/ or clouds/, template/volume.msh)
#     ──softcap capture──▶ <OUT>/<S>/capture.mcap        world-frame point clouds (/capture/points)
#     ──softcap tissue track──▶ <OUT>/<S>/track.mcap     tracked tet mesh per frame (/tissue/track/nodes)
#     ──softcap tissue fit-dynamic──▶ <OUT>/<S>/dynamic.mcap, dynamic.json, report/   E, ν, α, β, rest shape
#
# Every target is a file; `make -j` tracks independent sessions in parallel:
#
#   softcap synth --scenario fixtures/scenarios/dynamic/bar-release.toml --out sessions/dyn/bar
#   make -f pipelines/dynamic.mk SESSIONS=sessions/dyn OUT=out/dynamic -j2
#   make -f pipelines/dynamic.mk SESSIONS=sessions/dyn OUT=out/dynamic digests
SOFTCAP  ?= target/release/softcap
SESSIONS ?= sessions
OUT      ?= out/dynamic
TRACK_ARGS ?=
FIT_ARGS ?=

NAMES := $(sort $(patsubst $(SESSIONS)/%/session.toml,%,$(wildcard $(SESSIONS)/*/session.toml)))

.PHONY: all digests clean-dynamic
.DELETE_ON_ERROR:
.SECONDARY:

all: $(foreach s,$(NAMES),$(OUT)/$(s)/dynamic.mcap)

$(OUT)/%/capture.mcap: $(SESSIONS)/%/session.toml
	@mkdir -p $(@D)
	$(SOFTCAP) capture $(SESSIONS)/$* -o $@

$(OUT)/%/track.mcap: $(OUT)/%/capture.mcap $(SESSIONS)/%/template/volume.msh
	$(SOFTCAP) tissue track $< --mesh $(SESSIONS)/$*/template/volume.msh --quiet $(TRACK_ARGS) -o $@

$(OUT)/%/dynamic.mcap: $(OUT)/%/track.mcap $(SESSIONS)/%/template/volume.msh
	$(SOFTCAP) tissue fit-dynamic $< --mesh $(SESSIONS)/$*/template/volume.msh --json $(@D)/dynamic.json \
	    --report $(@D)/report --quiet $(FIT_ARGS) -o $@

digests: all
	@for s in $(NAMES); do for f in capture track dynamic; do \
	    printf '%s/%s.mcap %s\n' "$$s" "$$f" "$$($(SOFTCAP) inspect digest $(OUT)/$$s/$$f.mcap)"; done; done

clean-dynamic:
	rm -rf $(OUT)
