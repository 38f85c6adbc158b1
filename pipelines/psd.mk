# pipelines/psd.mk — pose-space details for faces (bickel2008 / thesis ch. 5, docs/psd.md):
#
#   <MARKERS>/<T>.mcap or <T>.csv (handle trajectory: /capture/markers, or frame,handle,x_cm,y_cm,z_cm)
#     ──softcap psd animate──▶ <OUT>/<T>/face.mcap     WPSD face (/face/mesh), shell (/psd/large_scale)
#
# Every target is a file; `make -j` animates independent takes in parallel:
#
#   softcap psd markers --out markers/heldout.mcap          # a trajectory through held-out poses
#   make -f pipelines/psd.mk MARKERS=markers OUT=out/psd -j2
#   make -f pipelines/psd.mk MARKERS=markers OUT=out/psd digests
SOFTCAP  ?= target/release/softcap
MARKERS  ?= markers
OUT      ?= out/psd
FIXTURES ?= fixtures/ict-face
POSES    ?= 6

TAKE_NAMES := $(sort $(patsubst $(MARKERS)/%.mcap,%,$(wildcard $(MARKERS)/*.mcap)) \
                     $(patsubst $(MARKERS)/%.csv,%,$(wildcard $(MARKERS)/*.csv)))

.PHONY: all digests clean-psd
.DELETE_ON_ERROR:
.SECONDARY:
.SECONDEXPANSION:

all: $(foreach t,$(TAKE_NAMES),$(OUT)/$(t)/face.mcap)

# A take is its .mcap when there is one, else its .csv.
$(OUT)/%/face.mcap: $$(firstword $$(wildcard $(MARKERS)/$$*.mcap $(MARKERS)/$$*.csv))
	@mkdir -p $(@D)
	$(SOFTCAP) psd animate --fixtures $(FIXTURES) --markers $< --poses $(POSES) --out $@

digests: all
	@for t in $(TAKE_NAMES); do \
	    printf '%s/face.mcap %s\n' "$$t" "$$($(SOFTCAP) inspect digest $(OUT)/$$t/face.mcap)"; done

clean-psd:
	rm -rf $(OUT)
