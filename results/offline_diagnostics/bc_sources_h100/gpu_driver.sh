#!/bin/bash
# Session 14, call G: BC on each source of the Franka `mixed` data at 10 Hz (bc_sources.py).
END=$(( $(date +%s) + 470 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; mkdir -p $W
python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --actor nn_residual --envs franka --out $W --expert-scale 100 --stage collect 2>&1 | grep collect
timeout $(( END - $(date +%s) )) python3 results/offline_diagnostics/bc_sources_h100/bc_sources.py $W/data franka 2>&1 | grep -v warp | tee $OUT/output.txt
