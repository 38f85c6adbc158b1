# pipelines/design.mk — layered material design (bickel2010 / thesis ch. 8), one stage binary per rule:
#
#   base materials ──softcap design library──▶ <OUT>/library.json       (MATERIALS unset: the nine
#                                                                         reference base materials)
#   <TARGETS>/<T>.json (desired force–displacement behaviour)
#     ──softcap design search──▶ <OUT>/<T>/design.json, curves.png       (branch-and-bound, §8.4)
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

.PHONY: all clean-design
.DELETE_ON_ERROR:
.SECONDARY:

all: $(foreach t,$(TARGET_NAMES),$(OUT)/$(t)/design.json)

$(OUT)/library.json:
	@mkdir -p $(@D)
	$(SOFTCAP) design library -o $@

$(OUT)/%/design.json: $(TARGETS)/%.json $(MATERIALS)
	@mkdir -p $(@D)
	$(SOFTCAP) design search --materials $(MATERIALS) --target $< --clusters $(CLUSTERS) -o $(@D)

clean-design:
	rm -rf $(OUT)
