# bcbench: every target sets itself up; `make test`, `make demo` and `make smoke` work on a fresh clone.
VENV    ?= .venv
PY      := $(VENV)/bin/python
PIP     := $(PY) -m pip
STAMP   := $(VENV)/.bcbench-installed
# The CPU build of torch lies in a local wheel directory on the project's machines.
WHEELS  := $(wildcard /opt/wheels)
PIPOPTS := -q $(if $(WHEELS),--find-links $(WHEELS),)

.PHONY: install test test-sidecar lint demo smoke clean lerobot-env reports
LEROBOT_VENV ?= .lerobot-venv
LEROBOT_PY   ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.12*/bin/python3.12) $(shell command -v python3.12))

install: $(STAMP)

# Re-runs only when pyproject.toml changes (idempotent and fast otherwise).
$(STAMP): pyproject.toml
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PIP) install $(PIPOPTS) torch==2.13.0
	$(PIP) install $(PIPOPTS) -e '.[dev,ray,metaworld]'
	@touch $(STAMP)
	@echo "installed: run bcbench as .venv/bin/bcbench, or first: source $(VENV)/bin/activate"

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

# The main job, on this machine: the simulator checked against the data, then every published model (models/) timed
# here, re-scored on 5 test episodes against its committed scores, and read at the delay its latency implies at
# 10 Hz from the committed real-time sweeps; prints the answer and writes one page with a rollout video.
demo: install
	@start=$$(date +%s); \
	$(VENV)/bin/bcbench data replay --quiet --out runs/demo/replay.json && \
	$(VENV)/bin/bcbench choose --quiet --out runs/demo/choose && \
	echo "" && \
	echo "demo done in $$(( $$(date +%s) - start )) s on$$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2) ($$(nproc) cores)." && \
	echo "  the answer, as a page (open in a browser): runs/demo/choose/choose.html  (Markdown: choose.md)" && \
	echo "  simulator replay check:                    runs/demo/replay.json" && \
	echo "  rollout video of the chosen policy:        runs/demo/choose/rollout/videos/" && \
	echo "  the converged CPU study it reads from:     results/cpu-confirm/report/report.html" && \
	echo "  run bcbench yourself: source $(VENV)/bin/activate  (then bcbench --help)"

# The whole pipeline at smoke size (what `make demo` was): trains, scores and times every policy in a minute or two
# each; its models are not converged and its report gives no verdicts on them.
smoke: install
	$(VENV)/bin/bcbench data replay --quiet --out runs/smoke/replay.json
	$(VENV)/bin/bcbench eval --policy scripted --episodes 4 --video 2 --quiet --out runs/smoke/videos
	$(VENV)/bin/bcbench study studies/demo.toml --out runs/smoke/study
	@echo ""
	@echo "smoke done. Its models are smoke-sized (a minute or two of training each): the report marks them"
	@echo "not converged and gives no verdicts on them. The converged CPU study: results/cpu-confirm/report/report.html"
	@echo "  report (open in a browser): runs/smoke/study/report/report.html  (Markdown: report.md)"
	@echo "  simulator replay check:     runs/smoke/replay.json"
	@echo "  rollout videos:             runs/smoke/videos/videos/"

clean:
	rm -rf $(VENV) $(LEROBOT_VENV) runs build src/*.egg-info .pytest_cache .ruff_cache
