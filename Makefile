# make demo: the main job on built-in defaults.  make test: the test suite.
# Both build .venv on first use (Debian packages, venv, pinned pip install).
# The demo's loco run leaves out N3M, SIFT + PnP and SMM (instance-level methods: at chance on unseen classes,
# and 2.5 of its minutes); its last step runs every method on a small Fig. 5 set.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
DEMO   ?= out/demo
export PYOPENGL_PLATFORM ?= egl

.PHONY: demo test test-fast install bench clean

$(VENV)/.installed: pyproject.toml constraints.txt scripts/install-system-deps.sh
	bash scripts/install-system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[dev,blender,ray,learn]"
	touch $@

install: $(VENV)/.installed

demo: install
	$(BIN)/spm-data render --all --limit 96 --out $(DEMO)/render
	$(BIN)/spm-data info $(DEMO)/render
	$(BIN)/spm-data show $(DEMO)/render/cup-00000.h5 --out $(DEMO)/cup-sheet.png
	$(BIN)/spm-data occlude $(DEMO)/render --out $(DEMO)/occluded --max 0.6 --copies 2
	$(BIN)/spm-data hist $(DEMO)/occluded --out $(DEMO)/occlusion-hist.png
	$(BIN)/spm-data show $(DEMO)/occluded/cup-00000-occ0.h5 --out $(DEMO)/cup-occluded-sheet.png
	$(BIN)/spm train $(DEMO) --out $(DEMO)/report --workers 2 --runs 1 --methods spm,knn1,knn3,pca,ls,template,chance
	$(BIN)/python benchmarks/fig5.py --quick --out $(DEMO)-fig5
	@echo "demo output: $(DEMO)/ (shards in render/ and occluded/, contact sheets, the occlusion histogram, report/ with results.md, accuracy.png, model.npz and reference-model.npz; and $(DEMO)-fig5/report: the paper's Fig. 5 off the grid)"

# ruff first (pyproject.toml [tool.ruff]: pyflakes' checks, lines of at most 120 characters), then
# -n auto: one pytest worker per core (pytest-xdist); the tests share no files and each
# worker builds its own session fixtures.
test: install
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q -n auto

# The edit loop: everything but the tests marked slow (Blender, killed or raced processes, Ray,
# the full benchmark of every method).
test-fast: install
	$(BIN)/python -m pytest -q -n auto -m "not slow"

bench: install
	$(BIN)/python benchmarks/render_throughput.py

clean:
	rm -rf $(VENV) out .pytest_cache
