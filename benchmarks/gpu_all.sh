#!/usr/bin/env bash
# The whole benchmark set on a GPU machine, in one go, within 10 minutes.
#
#   bash scripts/setup.sh && bash benchmarks/gpu_all.sh [OUT]
#
# Each rendering benchmark runs with the CUDA variant and, for comparison in
# the same run, with the LLVM (CPU) variant; the numpy benchmarks
# (reconstruction, stereo matching) run once on the machine's cores; the
# data-set benchmark runs with the CUDA variant at a small size. The last
# lines of each go to OUT/summary.txt (default: gpu-benchmarks/), its whole
# output to OUT/NAME.log.
#
# Every step has its own time limit and the set has one of 600 s: a step gets
# the smaller of its limit and what is left of the set's, and is skipped when
# under 10 s are left. A step that fails, times out or is skipped is reported
# in the summary, not fatal; the script's exit status is 0 when every step
# finished.
set -u
cd "$(dirname "$0")/.."
OUT="${1:-gpu-benchmarks}"
BUDGET=600
mkdir -p "$OUT"
PY=.venv/bin/python
[ -x "$PY" ] || PY=python3
START=$SECONDS
FAILED=0
"$PY" -c "import mitsuba as mi, drjit as dr; print('mitsuba', mi.__version__, 'drjit', dr.__version__, 'variants', mi.variants(), 'cuda', dr.has_backend(dr.JitBackend.CUDA))" | tee "$OUT/summary.txt"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$OUT/summary.txt"
echo "cores: $(nproc)" | tee -a "$OUT/summary.txt"

run() {  # run NAME SECONDS COMMAND...
  local name=$1 limit=$2; shift 2
  local left=$((BUDGET - (SECONDS - START)))
  [ "$left" -lt "$limit" ] && limit=$left
  echo "== $name (limit ${limit} s)" | tee -a "$OUT/summary.txt"
  if [ "$limit" -lt 10 ]; then
    echo "$name: skipped, ${left} s left of the set's ${BUDGET} s" | tee -a "$OUT/summary.txt"
    FAILED=1
    return
  fi
  local t0=$SECONDS
  if timeout "$limit" "$@" > "$OUT/$name.log" 2>&1; then
    tail -n 3 "$OUT/$name.log" | tee -a "$OUT/summary.txt"
  else
    echo "$name: failed or timed out (exit $?); see $name.log" | tee -a "$OUT/summary.txt"
    tail -n 5 "$OUT/$name.log" | tee -a "$OUT/summary.txt"
    FAILED=1
  fi
  echo "$name: $((SECONDS - t0)) s" | tee -a "$OUT/summary.txt"
}

for v in cuda_ad_mono llvm_ad_mono; do
  run "render_sphere_$v" 100 "$PY" benchmarks/render_stack.py --variant "$v" --repeats 5
  run "render_solder_$v" 100 "$PY" benchmarks/render_stack.py --scene solder --variant "$v" --ref-spp 256 --repeats 3
done
run reconstruct 45 "$PY" benchmarks/reconstruct.py
run stereo_match 60 "$PY" benchmarks/stereo_match.py --repeats 3
run dataset_cuda_ad_mono 90 "$PY" benchmarks/dataset.py --variant cuda_ad_mono --items 16 --solder-items 4 --memory-items 100
echo "total: $((SECONDS - START)) s of ${BUDGET} s" | tee -a "$OUT/summary.txt"
echo "summary: $OUT/summary.txt"
exit $FAILED
