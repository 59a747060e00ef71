#!/bin/bash
# Session 14, call F: chapter-7 table at 10 Hz with 100 expert episodes and terminals removed
# (--remove-terminals; ANCHOR_FACTS §5 asks for both settings), Franka: MAHALO, RP, BC, BCO in RL-expert and RL-sample; both
# environments: the Oracle on `mixed` (ILfO) and on `mixed` + expert (IL); Franka RLfO BCO.
# Starts from the committed results/ch7_10hz/results.jsonl; every process's time limit comes from one deadline.
END=$(( $(date +%s) + 560 ))
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site:. PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
W=/tmp/ch7_10hz; O=$OUT/x; mkdir -p $O $W
cp results/ch7_10hz/results.jsonl $W/results.jsonl
A="python3 scripts/reproduce_ch7.py --preset gpu --substeps 24 --scale 400 --steps 50000 --chunk 50000 --actor nn_residual --out $W --expert-scale 100 --remove-terminals"
H="$A --envs franka"; L="$A --envs three_link/env3"
timeout $(( END - $(date +%s) - 400 )) $A --envs franka three_link/env3 --stage collect > $O/collect100.log 2>&1
T="timeout $(( END - $(date +%s) ))"
for s in RL-expert RL-sample; do for l in MAHALO RP; do $T $H --stage train --scenarios $s --learners $l > $O/t_${s}_$l.log 2>&1 & done; done
for s in ILfO IL; do $T $H --stage train --scenarios $s --learners Oracle > $O/t_${s}_Oracle.log 2>&1 & done
for s in ILfO IL; do $T $L --stage train --scenarios $s --learners Oracle > $O/t_3link_${s}_Oracle.log 2>&1 & done
$T $H --stage train --scenarios RL-expert --learners BC BCO > $O/t_bc_expert.log 2>&1 &
$T $H --stage train --scenarios RL-sample --learners BC BCO > $O/t_bc_sample.log 2>&1 &
$T $H --stage train --scenarios RLfO --learners BCO > $O/t_bco_rlfo.log 2>&1 &  # call E ran out of time before it
wait
mkdir -p $W/logs_f; cp $O/*.log $W/logs_f/; cd /tmp && tar czf $OUT/ch7_10hz_f.tgz --exclude='ch7_10hz/data' ch7_10hz
grep -h "\[collect\]" $O/collect100.log | tail -3; grep -h "\[train\]" $O/t*.log
