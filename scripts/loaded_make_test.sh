#!/usr/bin/env bash
# `make test` N times in a row (default 5) while two busy loops keep both cores loaded; prints how
# many passed. The suite must not depend on wall-clock timing being kind.
#   scripts/loaded_make_test.sh [N]
set -u
cd "$(dirname "$0")/.."
runs=${1:-5}
burn() { while :; do :; done; }
burn & b1=$!
burn & b2=$!
trap 'kill $b1 $b2 2>/dev/null' EXIT
mkdir -p runs
passed=0
for i in $(seq 1 "$runs"); do
  if make test > "runs/loaded-make-test-$i.log" 2>&1; then
    passed=$((passed + 1)); echo "run $i: passed ($(tail -n 1 "runs/loaded-make-test-$i.log"))"
  else
    echo "run $i: FAILED, see runs/loaded-make-test-$i.log"; grep -E '^FAILED' "runs/loaded-make-test-$i.log"
  fi
done
echo "$passed of $runs runs of make test passed with both cores loaded"
[ "$passed" -eq "$runs" ]
