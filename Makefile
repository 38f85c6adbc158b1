# softcap: the two commands of the README.
#   make demo   run the main job on the embedded default
#   make test   run the tests
# Until the tissue and diagnose stages land, the demo runs the furthest stage that works:
# capture on the committed example session fixtures/session-min.
CARGO ?= cargo
TARGET_DIR ?= $(or $(CARGO_TARGET_DIR),target)
BIN := $(TARGET_DIR)/release
OUT := out/demo

.PHONY: demo test build
build:
	$(CARGO) build --release --workspace --bins

test:
	$(CARGO) test --workspace

demo: build
	@mkdir -p $(OUT)
	$(BIN)/softcap capture fixtures/session-min -o $(OUT)/capture.mcap
	$(BIN)/softcap inspect summary $(OUT)/capture.mcap
	$(BIN)/softcap inspect export $(OUT)/capture.mcap --what markers -o $(OUT)/markers.csv
	$(BIN)/softcap inspect export $(OUT)/capture.mcap --what probe -o $(OUT)/probe.csv
	@echo
	@echo "demo: capture.mcap, markers.csv and probe.csv are in $(OUT)/"
	@echo "      look inside with: $(BIN)/softcap inspect dump $(OUT)/capture.mcap | head"
