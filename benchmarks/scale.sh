#!/bin/bash
# Wall times of the gate serially, with -j 2 and on a 2-worker local Dask cluster (the
# README's table). References are built into copies of the scenes under $OUT, never over
# the committed ones. Usage: benchmarks/scale.sh [OUT]   (from the repository root)
# Environment: SUITE_MODES / REF_MODES (default "serial j2 dask"; empty skips), SUITE_ARGS
# (default: the whole full suite), REF_SPP / REF_PASSES (default 256 / 16: the defaults).
set -u
PY=${PY:-.venv/bin/python}
OUT=${1:-/tmp/scale-bench}
export PYTHONPATH=$PWD
mkdir -p "$OUT/scenes"
cp -r reference/scenes/. "$OUT/scenes/" && rm -rf "$OUT"/scenes/*/ref
SCENES=$(ls -d "$OUT"/scenes/*/)
[ -n "$SCENES" ] || exit 1
t() {
  local label=$1; shift
  local t0=$(date +%s.%N)
  "$@" > "$OUT/$label.log" 2>&1
  echo "$label rc=$? $(python3 -c "print(round($(date +%s.%N) - $t0, 1))") s"
}
$PY -m dask scheduler --scheduler-file "$OUT/sched.json" --no-dashboard > "$OUT/sched.log" 2>&1 &
SCHED=$!
sleep 8
$PY -m dask worker --scheduler-file "$OUT/sched.json" --nworkers 2 --nthreads 1 \
  --no-dashboard > "$OUT/workers.log" 2>&1 &
WORKERS=$!
sleep 10
read -r -a SUITE_EXTRA <<< "${SUITE_ARGS:-}"
for mode in ${SUITE_MODES-serial j2 dask}; do
  case $mode in serial) opt=();; j2) opt=(-j 2);; dask) opt=(--dask-scheduler-file "$OUT/sched.json");; esac
  t "suite-$mode" $PY -m mcverify check --suite full -q --json "$OUT/suite-$mode.json" \
    "${SUITE_EXTRA[@]}" "${opt[@]}"
done
for mode in ${REF_MODES-serial j2 dask}; do
  case $mode in serial) opt=();; j2) opt=(-j 2);; dask) opt=(--dask-scheduler-file "$OUT/sched.json");; esac
  t "ref-$mode" $PY -m mcverify reference build $SCENES --spp "${REF_SPP:-256}" \
    --passes "${REF_PASSES:-16}" -q "${opt[@]}"
done
kill $WORKERS; sleep 3; kill $SCHED
