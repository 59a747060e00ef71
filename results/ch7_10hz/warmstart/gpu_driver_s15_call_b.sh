#!/bin/bash
# Session 15 call B: Franka ILfO at 10 Hz (100 expert episodes): does a longer BC warm start (half of the 50 k steps, BC's own level) lift MAHALO and the Oracle above BC of mixed? Curves at 25 k and 50 k steps.
END=$(( $(date +%s) + 565 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_franka_ws; O=$OUT/x; mkdir -p $O $W
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 25000 --curve --actor nn_residual --envs franka --out $W --expert-scale 100 --scenarios ILfO"
timeout $(( END - $(date +%s) - 400 )) $H --stage collect > $O/collect.log 2>&1
T="timeout $(( END - $(date +%s) - 20 ))"
for l in MAHALO Oracle RP; do $T $H --warmstart 0.5 --stage train --learners $l > $O/t_ws05_$l.log 2>&1 & done
$T $H --stage train --learners MAHALO > $O/t_ws01_MAHALO.log 2>&1 &
$T $H --stage train --learners BC > $O/t_BC.log 2>&1 &
wait
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_franka_ws.tgz --exclude='ch7_franka_ws/data' ch7_franka_ws
grep -h "\[collect\]" $O/collect.log | tail -3; grep -h "\[train\]\|\[time\]\|curve\|Error" $O/t*.log
