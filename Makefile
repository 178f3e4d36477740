# The README's quick start: `make demo` runs the main job, `make test` the test suite.
# Each installs what it needs first (scripts/setup.sh is idempotent).
.PHONY: setup demo test lint bench docs-pictures

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/scratchfab run demo

test: setup
	.venv/bin/python -m pytest -q

lint: setup
	.venv/bin/ruff check scratchfab tests benchmarks
	.venv/bin/mypy scratchfab benchmarks

bench: setup
	for b in benchmarks/bench_*.py; do .venv/bin/python $$b; done

# The README's pictures, from the demo's own outputs (run after a change to the demo's result).
docs-pictures: demo
	cp job-demo/optimize/side_by_side.png docs/demo.png
	cp job-demo/verify/sweep.gif docs/demo-sweep.gif
