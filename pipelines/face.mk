# pipelines/face.mk — facial performance capture, one stage binary per rule:
#
#   <TAKES>/<T>.csv (AnimFace-style mocap take) + FACE (scan .obj) + LANDMARKS (marker → vertex table)
#     ──softcap face run──▶ <OUT>/<T>/face.mcap         animated face (/face/mesh), wrinkles (/face/wrinkles)
#     ──softcap face animate──▶ <OUT>/<T>/renders/      PNG renders of selected frames
#   <OUT>/landmarks.csv ◀──softcap face landmarks── first take + FACE   (only when LANDMARKS is unset)
#
# Every target is a file; `make -j` animates independent takes in parallel:
#
#   make -f pipelines/face.mk TAKES=fixtures/animface-mocap FACE=fixtures/ict-face/neutral.obj \
#        LANDMARKS=fixtures/animface-mocap/ict_landmarks.csv OUT=out/face -j2
#   make -f pipelines/face.mk ... digests           # one `softcap inspect digest` per face.mcap
#
# Face takes (image sequences, docs/face.md "Face takes"): every <FACE_TAKES>/<T>/ with a cameras.toml
#     ──softcap face track──▶ <OUT>/takes/<T>/wrinkles.mcap (+ report/ figures)
#     ──softcap face run --wrinkles──▶ <OUT>/takes/<T>/face.mcap
#
#   make -f pipelines/face.mk takes FACE_TAKES=fixtures/face-takes \
#        LANDMARKS=fixtures/animface-mocap/ict_landmarks.csv OUT=out/face
#
# A take's optional wrinkle input (tracked curves + camera, `softcap_face::WrinkleInput` JSON) is
# <TAKES>/<T>.wrinkles.json; when present it is passed with --wrinkles and those frames are synthesized.
SOFTCAP   ?= target/release/softcap
TAKES     ?= fixtures/animface-mocap
FACE      ?= fixtures/ict-face/neutral.obj
OUT       ?= out/face
LANDMARKS ?= $(OUT)/landmarks.csv
STRIDE    ?= 4
RENDER_FRAMES ?= 0,150,390
FACE_TAKES ?= fixtures/face-takes

TAKE_NAMES := $(filter-out ict_landmarks,$(patsubst $(TAKES)/%.csv,%,$(wildcard $(TAKES)/*.csv)))
FIRST_TAKE := $(firstword $(TAKE_NAMES))
FACE_TAKE_NAMES := $(patsubst $(FACE_TAKES)/%/cameras.toml,%,$(wildcard $(FACE_TAKES)/*/cameras.toml))

.PHONY: all renders takes digests clean-face
.DELETE_ON_ERROR:
.SECONDARY:
.SECONDEXPANSION:

all: $(foreach t,$(TAKE_NAMES),$(OUT)/$(t)/face.mcap)
renders: $(foreach t,$(TAKE_NAMES),$(OUT)/$(t)/renders/.done)
takes: $(foreach t,$(FACE_TAKE_NAMES),$(OUT)/takes/$(t)/face.mcap)

# Derived landmark table (ICP + closest vertex) when none is given.
$(OUT)/landmarks.csv: $(TAKES)/$(FIRST_TAKE).csv $(FACE)
	@mkdir -p $(@D)
	$(SOFTCAP) face landmarks --mocap $< --face $(FACE) -o $@

$(OUT)/%/face.mcap: $(TAKES)/%.csv $(FACE) $(LANDMARKS) $$(wildcard $(TAKES)/$$*.wrinkles.json)
	@mkdir -p $(@D)
	$(SOFTCAP) face run --mocap $< --face $(FACE) --landmarks $(LANDMARKS) --stride $(STRIDE) \
	    $(if $(wildcard $(TAKES)/$*.wrinkles.json),--wrinkles $(TAKES)/$*.wrinkles.json) -o $@

$(OUT)/%/renders/.done: $(TAKES)/%.csv $(FACE) $(LANDMARKS)
	@mkdir -p $(@D)
	$(SOFTCAP) face animate --mocap $< --face $(FACE) --landmarks $(LANDMARKS) \
	    --frames $(RENDER_FRAMES) --out $(@D)
	@touch $@

# A face take: wrinkles tracked in its frames, then synthesized on the animated face.
$(OUT)/takes/%/wrinkles.mcap: $(FACE_TAKES)/%/cameras.toml $(FACE_TAKES)/%/mocap.csv $(FACE) $(LANDMARKS) \
        $$(wildcard $(FACE_TAKES)/$$*/frames/*/*.png) $$(wildcard $(FACE_TAKES)/$$*/labels/*.png)
	@mkdir -p $(@D)
	$(SOFTCAP) face track $(FACE_TAKES)/$* --face $(FACE) --landmarks $(LANDMARKS) \
	    --report $(@D)/report -o $@

$(OUT)/takes/%/face.mcap: $(OUT)/takes/%/wrinkles.mcap $(FACE_TAKES)/%/mocap.csv $(FACE) $(LANDMARKS)
	$(SOFTCAP) face run --mocap $(FACE_TAKES)/$*/mocap.csv --face $(FACE) --landmarks $(LANDMARKS) \
	    --wrinkles $< -o $@

digests: all
	@for t in $(TAKE_NAMES); do \
	    printf '%s/face.mcap %s\n' "$$t" "$$($(SOFTCAP) inspect digest $(OUT)/$$t/face.mcap)"; done

clean-face:
	rm -rf $(OUT)
