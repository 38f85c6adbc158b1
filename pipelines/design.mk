# pipelines/design.mk — layered material design (bickel2010 / thesis ch. 8), one stage binary per rule:
#
#   base materials ──softcap design library──▶ <OUT>/library.json       (MATERIALS unset: the nine
#                                                                         reference base materials)
#   <TARGETS>/<T>.json (desired force–displacement behaviour)
#     ──softcap design search──▶ <OUT>/<T>/design.mcap (/design/report + provenance),
#                                 design.json, design.3mf, curves.png      (branch-and-bound, §8.4)
#
#   make -f pipelines/design.mk TARGETS=goals OUT=out/design digests   # `softcap inspect digest`
#                                                                      # of every design.mcap
#
# `make -j` searches independent targets in parallel:
#
#   make -f pipelines/design.mk TARGETS=goals OUT=out/design -j2
#   make -f pipelines/design.mk TARGETS=goals OUT=out/design MATERIALS=my-library.json
#
# A target can itself be made from a known design (to check that the search finds it):
#   softcap design target --materials out/design/library.json --design 7,6,2,5,1 -o goals/t1.json
SOFTCAP   ?= target/release/softcap
TARGETS   ?= targets
OUT       ?= out/design
MATERIALS ?= $(OUT)/library.json
CLUSTERS  ?= 20

TARGET_NAMES := $(patsubst $(TARGETS)/%.json,%,$(wildcard $(TARGETS)/*.json))

.PHONY: all digests clean-design
.DELETE_ON_ERROR:
.SECONDARY:

DESIGNS := $(foreach t,$(TARGET_NAMES),$(OUT)/$(t)/design.mcap)

all: $(DESIGNS)

$(OUT)/library.json:
	@mkdir -p $(@D)
	$(SOFTCAP) design library -o $@

$(OUT)/%/design.mcap: $(TARGETS)/%.json $(MATERIALS)
	@mkdir -p $(@D)
	$(SOFTCAP) design search --materials $(MATERIALS) --target $< --clusters $(CLUSTERS) -o $(@D)

# `softcap inspect digest` of every design, one line per file (what `make verify` compares).
digests: $(DESIGNS)
	@for f in $(DESIGNS); do printf '%s %s\n' "$$f" "$$($(SOFTCAP) inspect digest $$f)"; done

clean-design:
	rm -rf $(OUT)
