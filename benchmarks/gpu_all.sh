#!/usr/bin/env bash
# The whole benchmark set on a GPU machine, in one go (about 5 minutes on one
# data-centre GPU; every step is bounded by `timeout`, 10 minutes in all).
#
#   bash scripts/setup.sh && bash benchmarks/gpu_all.sh [OUT]
#
# Each benchmark runs with the CUDA variant and, for comparison in the same
# run, with the LLVM (CPU) variant; the last lines of each are collected in
# OUT/summary.txt (default: gpu-benchmarks/). A variant that cannot run here
# is reported, not fatal.
set -u
cd "$(dirname "$0")/.."
OUT="${1:-gpu-benchmarks}"
mkdir -p "$OUT"
PY=.venv/bin/python
[ -x "$PY" ] || PY=python3
"$PY" -c "import mitsuba as mi, drjit as dr; print('mitsuba', mi.__version__, 'drjit', dr.__version__, 'variants', mi.variants(), 'cuda', dr.has_backend(dr.JitBackend.CUDA))" | tee "$OUT/summary.txt"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$OUT/summary.txt"

run() {  # run NAME SECONDS COMMAND...
  local name=$1 limit=$2; shift 2
  echo "== $name" | tee -a "$OUT/summary.txt"
  if timeout "$limit" "$@" > "$OUT/$name.log" 2>&1; then
    tail -n 3 "$OUT/$name.log" | tee -a "$OUT/summary.txt"
  else
    echo "$name: failed or timed out (exit $?); see $name.log" | tee -a "$OUT/summary.txt"
    tail -n 5 "$OUT/$name.log" | tee -a "$OUT/summary.txt"
  fi
}

for v in cuda_ad_mono llvm_ad_mono; do
  run "render_sphere_$v" 150 "$PY" benchmarks/render_stack.py --variant "$v" --repeats 5
  run "render_solder_$v" 150 "$PY" benchmarks/render_stack.py --scene solder --variant "$v" --ref-spp 256 --repeats 3
done
run reconstruct 90 "$PY" benchmarks/reconstruct.py
echo "summary: $OUT/summary.txt"
