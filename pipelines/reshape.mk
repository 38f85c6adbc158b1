# pipelines/reshape.mk — template reshaping by plastic strains (saito-barbic; docs/reshape.md):
#
#   TEMPLATE (Gmsh 4.1 tet mesh) + <TARGETS>/<S>/ (target.toml, landmarks.csv, icp_markers.csv, …)
#     ──softcap tissue reshape──▶ <OUT>/<S>/reshaped.mcap (+ report/ figures)
#
# Every target is a file; `make -j` reshapes independent subjects in parallel:
#
#   cargo run --release -p softcap_tissue --example reshape_box -- /tmp/box
#   make -f pipelines/reshape.mk TEMPLATE=/tmp/box/template.msh TARGETS=/tmp/box OUT=out/reshape -j2
#   make -f pipelines/reshape.mk TEMPLATE=/tmp/box/template.msh TARGETS=/tmp/box OUT=out/reshape digests
SOFTCAP  ?= target/release/softcap
TEMPLATE ?= template.msh
TARGETS  ?= targets
OUT      ?= out/reshape
RESHAPE_ARGS ?=

NAMES := $(sort $(patsubst $(TARGETS)/%/target.toml,%,$(wildcard $(TARGETS)/*/target.toml)))

.PHONY: all digests clean-reshape
.DELETE_ON_ERROR:
.SECONDARY:
.SECONDEXPANSION:

all: $(foreach s,$(NAMES),$(OUT)/$(s)/reshaped.mcap)

$(OUT)/%/reshaped.mcap: $(TEMPLATE) $$(wildcard $(TARGETS)/$$*/*)
	@mkdir -p $(@D)
	$(SOFTCAP) tissue reshape --template $(TEMPLATE) --target $(TARGETS)/$* --report $(@D)/report \
	    --quiet $(RESHAPE_ARGS) -o $@

digests: all
	@for s in $(NAMES); do \
	    printf '%s/reshaped.mcap %s\n' "$$s" "$$($(SOFTCAP) inspect digest $(OUT)/$$s/reshaped.mcap)"; done

clean-reshape:
	rm -rf $(OUT)
