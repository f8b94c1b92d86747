#!/usr/bin/env bash
# Table I under the settled protocol (docs/evaluation.md, "The first attempt of a round"): every
# row of the test set, three seeds × 100 scenes per level, into one resumable run directory, the
# rows that decide issue 18 first (the oracle and the cell, the ablations under the cell's
# selection on seed 0, the cell with a memory of failed picks — session 46's candidate, not
# adopted —, the ablations' seeds 1 and 2), then the paper's-protocol rows (the paper's ablation
# steps without the cell's selection) on all seeds, then the baselines.
#
#   scripts/eval-table1-settled.sh [OUT]
#
# OUT defaults to ../data/table1-v2-settled (beside the checkout). On a new machine it starts from
# the stored records (data/eval-state/table1-v2-settled), so nothing finished is run again. Every
# step resumes where a killed run stopped (`psgrasp eval` keeps finished scenes); rerun the script
# with the same OUT to go on. ≈ 13.5 one-core hours in all on the 2-core machine (the oracle's
# challenging rounds are the slow part, ≈ 90 CPU-minutes per seed). Needs the release binary
# (`cargo build --release --features ort --bins`) and the fetched objects (scripts/fetch_objects.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-../data/table1-v2-settled}"
BIN="${CARGO_TARGET_DIR:-target}/release/psgrasp"
STATE=data/eval-state/table1-v2-settled
[ -x "$BIN" ] || { echo "no $BIN: cargo build --release --features ort --bins" >&2; exit 1; }
if [ ! -e "$OUT/run.json" ]; then
    mkdir -p "$OUT"
    cp "$STATE/run.json" "$OUT/"
    gunzip -c "$STATE/records.jsonl.gz" > "$OUT/records.jsonl"
fi
run() {
    echo "== $(date -u +%FT%TZ) $*"
    nice "$BIN" eval --detectors-file config/eval-detectors.toml --scenes 100 --jobs 2 \
        --config config/eval-protocol-franka-fingertip-settled.toml --out "$OUT" "$@"
}
CELL=w-kappa-8app-cell-walls-wide
# The cell with a memory of failed picks (session 46; measured, not adopted).
CELL_MEMORY=w-kappa-8app-cell-memory
ABLATIONS=w-kappa-1app-cell-walls-wide,wo-kappa-1app-cell-walls-wide
PAPER_ROWS=w-kappa-8app,w-kappa-1app,wo-kappa-1app
BASELINES=vgn,vgn-dense
ALL=easy,medium,challenging
run --detector "$CELL,oracle" --level challenging --seed 0,1,2
run --detector "$CELL,oracle" --level easy,medium --seed 0,1,2
run --detector "$ABLATIONS" --level "$ALL" --seed 0
run --detector "$CELL_MEMORY" --level challenging --seed 0,1,2
run --detector "$CELL_MEMORY" --level easy,medium --seed 0,1,2
run --detector "$ABLATIONS" --level "$ALL" --seed 1,2
run --detector "$PAPER_ROWS" --level "$ALL" --seed 0
run --detector "$PAPER_ROWS" --level "$ALL" --seed 1,2
run --detector "$BASELINES" --level "$ALL" --seed 0,1,2
# The report: each row paired with the one before it (the paper's κ and 8app steps, then the same
# steps under the cell's selection, the memory against the cell, the oracle last).
run --detector "$BASELINES,wo-kappa-1app,w-kappa-1app,w-kappa-8app,wo-kappa-1app-cell-walls-wide,w-kappa-1app-cell-walls-wide,$CELL,$CELL_MEMORY,oracle" \
    --level "$ALL" --seed 0,1,2 --report-only
echo "== $(date -u +%FT%TZ) done: $OUT/summary.md"
