#!/bin/bash
# Session 15 call D: twice the steps (100 k) with a quarter of them BC warm start (25 k, as --warmstart 0.5 at 50 k): MAHALO in ILfO at 10 Hz on both datasets.
END=$(( $(date +%s) + 390 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_franka_ws; O=$OUT/x; mkdir -p $O $W; rm -f $W/*.log
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 100000 --chunk 50000 --curve --warmstart 0.25 --actor nn_residual --out $W --expert-scale 100 --scenarios ILfO"
timeout $(( END - $(date +%s) - 250 )) $H --envs franka three_link/env3 --stage collect > $O/collect.log 2>&1
T="timeout $(( END - $(date +%s) - 15 ))"
for e in franka three_link/env3; do $T $H --envs $e --stage train --learners MAHALO > $O/t_${e%%/*}_MAHALO.log 2>&1 & done
wait
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_franka_ws_d.tgz --exclude='ch7_franka_ws/data' ch7_franka_ws
grep -h "\[collect\]" $O/collect.log | tail -4; grep -h "\[train\]\|\[time\]\|curve\|Error" $O/t*.log
