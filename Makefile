# softcap: the two commands of the README.
#   make demo   run the main job on the embedded default
#   make test   run the tests
CARGO ?= cargo

.PHONY: demo test build
build:
	$(CARGO) build --release --workspace --bins

test:
	$(CARGO) test --workspace

demo: build
	@echo "demo: no stage binary has landed yet; see README.md"
