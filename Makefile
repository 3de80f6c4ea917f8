# bcbench: every target sets itself up; `make test` and `make demo` work on a fresh clone.
VENV    ?= .venv
PY      := $(VENV)/bin/python
PIP     := $(PY) -m pip
STAMP   := $(VENV)/.bcbench-installed
# The CPU build of torch lies in a local wheel directory on the project's machines.
WHEELS  := $(wildcard /opt/wheels)
PIPOPTS := -q $(if $(WHEELS),--find-links $(WHEELS),)

.PHONY: install test test-sidecar lint demo clean lerobot-env reports
LEROBOT_VENV ?= .lerobot-venv
LEROBOT_PY   ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.12*/bin/python3.12) $(shell command -v python3.12))

install: $(STAMP)

# Re-runs only when pyproject.toml changes (idempotent and fast otherwise).
$(STAMP): pyproject.toml
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PIP) install $(PIPOPTS) torch==2.13.0
	$(PIP) install $(PIPOPTS) -e '.[dev,ray]'
	@touch $(STAMP)

lint: install
	$(VENV)/bin/ruff check src tests benchmarks

test: install lint
	$(VENV)/bin/pytest -q --durations=15 -m "not sidecar" -n auto --dist loadfile

# Every committed study's report rebuilt in place from its result files (no torch): run it after changing the
# analysis or a mixing-reason.txt, then commit; tests/test_committed_results.py checks they match.
reports: install
	@for md in results/*/report/report.md; do \
	  d=$${md%/report/report.md}; echo "report: $$d"; $(VENV)/bin/bcbench report "$$d" >/dev/null || exit 1; \
	done

# The LeRobot sidecar (opt-in): LeRobot 0.6.1 needs Python >= 3.12, torch < 2.12 and diffusers < 0.40, so it
# lives in its own venv (about 5.6 GB, 3-4 minutes). `bcbench eval --policy lerobot:FOLDER` finds it here.
lerobot-env: $(LEROBOT_VENV)/.installed
$(LEROBOT_VENV)/.installed:
	@test -n "$(LEROBOT_PY)" || { echo "error: LeRobot needs Python 3.12 (pyenv install 3.12)" >&2; exit 2; }
	$(LEROBOT_PY) -m venv $(LEROBOT_VENV)
	$(LEROBOT_VENV)/bin/pip install -q "lerobot[diffusion,pusht,training]==0.6.1"
	@touch $@

# The tests against LeRobot itself (tests/test_lerobot_sidecar.py; about 4 minutes): run where the sidecar is.
test-sidecar: install lerobot-env
	$(VENV)/bin/pytest -q --durations=10 -m sidecar

demo: install
	$(VENV)/bin/bcbench data replay --quiet --out runs/demo/replay.json
	$(VENV)/bin/bcbench eval --policy scripted --episodes 4 --video 2 --quiet --out runs/demo/videos
	$(VENV)/bin/bcbench study studies/demo.toml --out runs/demo/study
	@echo ""
	@echo "demo done. Its models are smoke-sized (a minute or two of training each): the report marks them"
	@echo "not converged and gives no verdicts on them. The converged CPU study: results/cpu/report/report.html"
	@echo "  report (open in a browser): runs/demo/study/report/report.html  (Markdown: report.md)"
	@echo "  simulator replay check:     runs/demo/replay.json"
	@echo "  rollout videos:             runs/demo/videos/videos/"

clean:
	rm -rf $(VENV) $(LEROBOT_VENV) runs build src/*.egg-info .pytest_cache .ruff_cache
