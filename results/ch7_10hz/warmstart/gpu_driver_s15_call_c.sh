#!/bin/bash
# Session 15 call C: BC warm start of half the steps (--warmstart 0.5), ILfO at 10 Hz with 100 expert episodes: the Franka row's other learners and a 10-seed MAHALO/BC repeat; MAHALO and the Oracle on the 3-link.
END=$(( $(date +%s) + 540 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_franka_ws; O=$OUT/x; mkdir -p $O $W; rm -f $W/*.log
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --out $W --expert-scale 100 --scenarios ILfO"
timeout $(( END - $(date +%s) - 400 )) $H --envs franka three_link/env3 --stage collect > $O/collect.log 2>&1
T="timeout $(( END - $(date +%s) - 20 ))"
for l in ATAC AP UDS; do $T $H --envs franka --warmstart 0.5 --stage train --learners $l > $O/t_f_ws05_$l.log 2>&1 & done
$T $H --envs franka --warmstart 0.5 --seeds 10 --stage train --learners MAHALO > $O/t_f_ws05_MAHALO_10.log 2>&1 &
$T $H --envs franka --warmstart 0.5 --seeds 10 --stage train --learners BC BCO > $O/t_f_BC_10.log 2>&1 &
for l in MAHALO Oracle; do $T $H --envs three_link/env3 --warmstart 0.5 --stage train --learners $l > $O/t_3_ws05_$l.log 2>&1 & done
wait
cp $O/*.log $W/; cd /tmp && tar czf $OUT/ch7_franka_ws_c.tgz --exclude='ch7_franka_ws/data' ch7_franka_ws
grep -h "\[collect\]" $O/collect.log | tail -4; grep -h "\[train\]\|\[time\]\|Error" $O/t*.log
