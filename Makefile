# Every target bootstraps .venv on a fresh machine (Python >= 3.11 and make are all it needs).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
# numpy's AVX-512 kernels, switched off for the second CI pass (the AVX2 path most laptops take)
NOAVX512 := X86_V4 AVX512_ICL AVX512_SKX AVX512F AVX512CD AVX512_SPR AVX512_CNL AVX512_CLX

.PHONY: demo test test-noavx512 bench lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test,ros2]'
	$(PY) -c 'import sim_core.flight as f, sim_core.world.ball as b, sim_core.sonar.precull as p, sim_core.sensors.kernels as s; f.warm_up(); b.warm_up(); p.warm_up(); s.warm_up()'  # compile the kernels once
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m hil_bridge.cli launch launch/demo.yaml --domain auto --duration 20 \
		--record out/demo.mcap --plot out/demo.png --overwrite

test: $(STAMP)
	$(PY) -m pytest -q

# the second pass checks float results on the AVX2 path; tests of nodes as processes, and those
# tests/conftest.py marks no_simd_float, hold none
test-noavx512: $(STAMP)
	NPY_DISABLE_CPU_FEATURES="$(NOAVX512)" $(PY) -m pytest -q -p no:cacheprovider -m "not processes and not no_simd_float"

bench: $(STAMP)
	$(PY) -m bench

lint: $(STAMP)
	$(PY) -m ruff check sim_core hil_bridge drivers ros2_bridge tests bench
	$(PY) -m mypy
	$(VENV)/bin/lint-imports --no-cache

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache .hypothesis
