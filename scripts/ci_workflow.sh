#!/usr/bin/env bash
# The workflow's end-to-end check (run by `make test` after pytest, which already lints and dry-runs):
# the tiny .test config end to end (results in .test/results/), a check that
# every table, figure and report is there, that a second run has nothing to do, and the HTML report.
#   PYTHON=.venv/bin/python scripts/ci_workflow.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python}"
smk() { "$PYTHON" -m snakemake "$@"; }

echo "== .test config, end to end"
rm -rf .test/results .test/logs .test/benchmarks .test/.snakemake .test/report.html
start=$(date +%s)
smk -c2 --directory .test
echo "end to end: $(( $(date +%s) - start )) s"

missing=0
for path in \
    results/tables/table1.{csv,md,tex} results/tables/table2.{csv,md,tex} \
    results/figures/{fig1_configuration,fig2_forward,fig3_backward,fig4_noise,theta_path,distances}.png \
    results/noise/distances.csv results/report/reproduction.md results/notebooks/report.html; do
    if [ ! -s ".test/$path" ]; then echo "missing: .test/$path"; missing=1; fi
done
[ "$missing" = 0 ]

echo "== a second run has nothing to do"
smk -n --directory .test | tee .test/logs/second_run.txt | grep -q "Nothing to be done"

echo "== snakemake --report"
smk --directory .test --report report.html
[ -s .test/report.html ]
echo "ci_workflow: all workflow checks passed"
