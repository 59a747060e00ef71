#!/bin/bash
# Session 14, call E: chapter-7 table at 10 Hz with 100 expert episodes and terminals removed
# (--remove-terminals; ANCHOR_FACTS §5 asks for both settings), Franka: MAHALO, RP, BC, BCO in ILfO, IL and RLfO.
# Starts from the committed results/ch7_10hz/results.jsonl; every process's time limit comes from one deadline.
END=$(( $(date +%s) + 560 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
cp results/ch7_10hz/results.jsonl $W/results.jsonl
H="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --envs franka --out $W --expert-scale 100 --remove-terminals"
timeout $(( END - $(date +%s) - 400 )) $H --stage collect > $O/collect100.log 2>&1
T="timeout $(( END - $(date +%s) ))"
for s in ILfO IL RLfO; do for l in MAHALO RP; do $T $H --stage train --scenarios $s --learners $l > $O/t_${s}_$l.log 2>&1 & done; done
$T $H --stage train --scenarios ILfO RLfO --learners BC BCO > $O/t_bc_mixed.log 2>&1 &
$T $H --stage train --scenarios IL --learners BC BCO > $O/t_bc_expert.log 2>&1 &
wait
mkdir -p $W/logs_e; cp $O/*.log $W/logs_e/; cd /tmp && tar czf $OUT/ch7_10hz_e.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[collect\]" $O/collect100.log | tail -3; grep -h "\[train\]" $O/t*.log
