# The two commands of the README: `make demo` and `make test`. Both create .venv first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# The full ModelNet40 data, when it sits beside the checkout (development and CI).
SHARED_DATA := ../shared/data/modelnet40/modelnet40_1024_int16.npz
export MASKNET_DATA ?= $(if $(wildcard $(SHARED_DATA)),$(abspath $(SHARED_DATA)),)

.PHONY: install demo test lint format sample clean relay

$(STAMP): pyproject.toml constraints.txt
	@echo "Installing masknet and its dependencies into $(VENV) (a few minutes the first time)..."
	@bash scripts/install-system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# The constraints file pins torch's version; the build comes from pip's index (README).
	$(BIN)/python -m pip install -q -c constraints.txt -e '.[dev]'
	@touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/masknet demo -o masknet_demo

test: install
	@bash scripts/install-system-deps.sh --test
	$(BIN)/python -m pytest -q

lint: install
	$(BIN)/ruff check src tests scripts
	$(BIN)/ruff format --check src tests scripts

format: install
	$(BIN)/ruff check --fix src tests
	$(BIN)/ruff format src tests

# Resume the relay training run of CrossMaskNet in the background (relay/crossmasknet_fpfh_seen20).
relay: install
	bash scripts/relay.sh start

# Rebuild the bundled sample from the ModelNet40 test split.
sample: install
	$(BIN)/masknet make-sample --data "$(MASKNET_DATA)" -o src/masknet/resources/modelnet40_sample.npz

clean:
	rm -rf $(VENV) masknet_demo .pytest_cache .ruff_cache
